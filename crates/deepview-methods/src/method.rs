//! The interface of the crate: [`MpiMethod`], a way of making an MPI from posed input views (every
//! method: `deepview`, `psv-mean`, `nearest`, `optimize`), asked by an [`MpiRequest`], reporting
//! [`MethodEvent`]s, answering a [`MadeMpi`].

use crate::error::MethodError;
use crate::planes::PlaneChoice;
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_mpi::Mpi;

/// What a method is asked for: an MPI from `inputs`.
#[derive(Clone, Copy, Debug)]
pub struct MpiRequest<'a> {
    /// The input views (RGB images and their cameras).
    pub inputs: &'a [(ImageF32, Camera)],
    /// The inputs' indices in their dataset (recorded with the plane rule and in messages); may be empty.
    pub ids: &'a [usize],
    /// The scene's depth bounds.
    pub near_far: (f64, f64),
    /// The camera the MPI will be seen from, when known (eval's target). Only methods whose
    /// [`MpiMethod::uses_target`] is true look at it: `nearest` takes the input nearest it (without it,
    /// the input nearest the inputs' centroid).
    pub toward: Option<&'a Camera>,
}

/// What a method reports while it works (libraries do not print; the program shows these).
#[derive(Clone, Copy, Debug)]
pub enum MethodEvent<'a> {
    /// The plane count was chosen.
    Planes(&'a PlaneChoice),
    /// The work starts on an MPI of `planes` planes of `width x height` (methods that know its size
    /// before they start).
    Start {
        planes: usize,
        width: u32,
        height: u32,
    },
    /// How the learned model's inference will run ([`deepview_net::infer::Plan::describe`]).
    Plan(&'a str),
    /// `done` of `total` steps are done.
    Progress { done: usize, total: usize },
}

/// An MPI a method made.
#[derive(Clone, Debug)]
pub struct MadeMpi {
    pub mpi: Mpi,
    /// How its planes were chosen (`None`: the method has a fixed count, as `nearest`'s one plane).
    pub planes: Option<PlaneChoice>,
    /// What else is worth saying about it (e.g. `view 4`, `loss 0.0123 -> 0.0042`).
    pub note: Option<String>,
}

/// A way of making an MPI from posed input views.
pub trait MpiMethod {
    /// The method's name (`deepview`, `psv-mean`, `nearest`, `optimize`).
    fn name(&self) -> &str;

    /// The number of input views the method needs, when it needs a fixed number (weights trained for
    /// K views); `None`: any number.
    fn views(&self) -> Option<usize> {
        None
    }

    /// Whether the MPI depends on [`MpiRequest::toward`].
    fn uses_target(&self) -> bool {
        false
    }

    /// The weights the method uses (learned methods), as reports name them.
    fn weights(&self) -> Option<String> {
        None
    }

    /// Make the MPI of `request`, reporting progress through `events`.
    fn make_mpi(
        &mut self,
        request: &MpiRequest<'_>,
        events: &mut dyn FnMut(MethodEvent<'_>),
    ) -> Result<MadeMpi, MethodError>;
}
