//! Synthetic scenes with ground truth: procedural planar layers ([`scene`]) rendered through a camera rig
//! (a generated light-field grid, or the cameras of any dataset folder) and written in that rig's own
//! format, plus the ground-truth MPI ([`write`]); and richer 3D scenes made on the fly for training
//! ([`procedural`]).

pub mod procedural;
pub mod scene;
pub mod write;

pub use scene::{Layer, SynthScene};
pub use write::{Rig, SynthError, SynthOptions, SynthOutput, synthesize, synthesize_as};
