//! Multiplane images (MPIs) and the paper's forward model on the CPU.
//!
//! Data flow: an [`Mpi`] (D RGBA planes, back to front, premultiplied colour in memory, in front of a
//! reference camera) is warped into any target camera by plane-induced homographies ([`warp`]), composited
//! with the over operator ([`composite`]), which also yields the per-plane net transmittance `T` and
//! accumulated over `A` (the paper's gradient components). [`psv`] is the inverse warp of an image onto the
//! planes (the plane sweep volume). [`io`] reads and writes the interoperable folder format, [`interchange`]
//! converts it to and from other tools' MPI formats, [`depth`] turns an MPI into depth and disparity maps.

pub mod agreement;
pub mod compact;
pub mod composite;
pub mod depth;
mod error;
pub mod interchange;
pub mod io;
pub mod mpi;
pub mod psv;
pub mod render;
pub mod simd;
pub mod warp;

pub use compact::{CompactOptions, Compacted, compact};
pub use composite::{RenderComponents, render_components};
pub use depth::{DepthMaps, depth_maps, turbo};
pub use error::MpiError;
pub use interchange::{ExportFormat, ExportReport, ImportFormat, detect_format, export, import};
pub use io::{MpiMeta, PlanesRule, read_mpi, write_mpi, write_mpi_with};
pub use mpi::{Mpi, MpiU8, Texel};
pub use psv::{PlaneSweepVolume, plane_sweep};
pub use render::{
    LOW_COVERAGE, coverage, frame_coverage, render, render_rgba8_into, render_rgba8_with,
    view_warning,
};
pub use simd::Occupancy;
pub use warp::{RowTaps, Sampler, target_to_plane_homographies};
