//! What inference reports while it runs.

/// Progress of [`super::infer_mpi`]: `done` of `total` tile-net steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InferProgress {
    pub done: usize,
    pub total: usize,
    pub net: usize,
}
