//! The differentiable forward model on burn tensors: homography warps, over-compositing with net
//! transmittance `T` and accumulated over `A`, plane sweep volumes and the paper's gradient components.
//!
//! Layouts (all `f32`, any device, differentiable w.r.t. every tensor argument):
//! - an MPI (or any stack of planes) is `[D, C, h, w]`, plane 0 the farthest (back to front), RGBA colour
//!   premultiplied;
//! - an image is `[3, h, w]`;
//! - homographies are row-major 3x3, mapping OUTPUT pixels to SOURCE pixels (continuous coordinates,
//!   pixel centres at +0.5).
//!
//! Sampling rule (identical to `deepview_mpi::warp`, including its f32 arithmetic): output pixel `(x, y)`
//! samples the source at `H (x + 0.5, y + 0.5, 1)`; a sample with `w <= 0` or outside `[0, W] x [0, H]` is
//! 0 (transparent, invalid); inside, bilinear interpolation between the four nearest texel centres,
//! clamped to the edge texel. The homographies are constants, so the sampling taps (indices and weights)
//! are computed on the CPU ([`WarpTable`]) and applied with one `select` (a gather; its backward is a
//! scatter-add) and a weighted sum: no `grid_sample`, whose backward is ~10x its forward on `flex`.

mod composite;
mod taps;
#[cfg(test)]
mod tests;
mod warp;

pub use composite::{
    Composite, Crops, GRADIENT_CHANNELS, composite, composite_burn, composite_scan,
    gradient_components, gradient_components_framed, image_tensor, plane_sweep_volume,
    plane_sweep_volume_framed, render_view, render_view_framed,
};
pub use taps::{Frames, Hom, TransposedTaps, WarpTable};
pub use warp::{
    crop_output, crop_source, invert, mpi_to_view_homographies, mul, warp_planes,
    warp_planes_grid_sample,
};
