//! What inference reports while it runs.

/// Progress of [`super::infer_mpi`]: `done` of `total` steps (on the CPU engine a plane of a net; on
/// the tiled path a tile of a net), `net` the net of the latest step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InferProgress {
    pub done: usize,
    pub total: usize,
    pub net: usize,
}
