//! The two interfaces of the crate: [`MpiMethod`], a way of making an MPI from posed input views (every
//! method: `deepview`, `psv-mean`, `nearest`, `optimize`), and [`Method`], what the eval runner scores (an
//! image of a target view). [`MpiPredictor`] makes any [`MpiMethod`] a [`Method`] by rendering its MPI
//! into the target, so `eval` scores exactly the MPI that `infer` writes.

use crate::error::EvalError;
use crate::planes::PlaneChoice;
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_mpi::{Mpi, PlanesRule};

/// A view-synthesis method as the eval runner sees it: input views with cameras in, the target view's
/// image out.
///
/// `predict` returns an image of the target camera's size with at least 3 channels (RGB first; a 4th channel,
/// e.g. a rendered alpha, is ignored by the metrics). `near_far` are the scene's depth bounds.
pub trait Method {
    fn name(&self) -> &str;
    fn predict(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError>;

    /// [`Method::predict`] told the inputs' dataset indices `ids` (the runner calls this; by default it
    /// is `predict`).
    fn predict_views(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        ids: &[usize],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError> {
        let _ = ids;
        self.predict(inputs, target, near_far)
    }

    /// The MPI the last prediction rendered and how its planes were chosen, for methods that make one.
    fn last_mpi(&self) -> Option<(&Mpi, Option<&PlanesRule>)> {
        None
    }
}

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
    ) -> Result<MadeMpi, EvalError>;
}

/// The request an MPI was made for: input cameras, their ids, the bounds and, when the method uses it,
/// the target camera.
type RequestKey = (Vec<Camera>, Vec<usize>, (f64, f64), Option<Camera>);

/// An [`MpiMethod`] scored by the eval runner: the MPI rendered into the target. The last MPI is kept, so
/// targets that share inputs (and, for `nearest`, the target) reuse it.
pub struct MpiPredictor<'e> {
    method: Box<dyn MpiMethod + 'e>,
    events: Box<dyn FnMut(MethodEvent<'_>) + 'e>,
    last: Option<(RequestKey, MadeMpi)>,
}

impl<'e> MpiPredictor<'e> {
    /// Score `method`, reporting its events to `events`.
    pub fn new(method: Box<dyn MpiMethod + 'e>, events: impl FnMut(MethodEvent<'_>) + 'e) -> Self {
        Self {
            method,
            events: Box::new(events),
            last: None,
        }
    }

    /// The method.
    pub fn method(&self) -> &dyn MpiMethod {
        self.method.as_ref()
    }

    /// Forget the last MPI (so that timings include making it).
    pub fn clear(&mut self) {
        self.last = None;
    }

    /// The MPI of `request` (the kept one when the request is the last one's).
    pub fn mpi(&mut self, request: &MpiRequest<'_>) -> Result<&MadeMpi, EvalError> {
        let key: RequestKey = (
            request.inputs.iter().map(|(_, c)| *c).collect(),
            request.ids.to_vec(),
            request.near_far,
            request
                .toward
                .filter(|_| self.method.uses_target())
                .copied(),
        );
        if self.last.as_ref().is_none_or(|(k, _)| *k != key) {
            self.last = None;
            let made = self.method.make_mpi(request, &mut *self.events)?;
            self.last = Some((key, made));
        }
        Ok(&self.last.as_ref().expect("just made").1)
    }
}

impl Method for MpiPredictor<'_> {
    fn name(&self) -> &str {
        self.method.name()
    }

    fn predict(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError> {
        self.predict_views(inputs, &[], target, near_far)
    }

    fn predict_views(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        ids: &[usize],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError> {
        let made = self.mpi(&MpiRequest {
            inputs,
            ids,
            near_far,
            toward: Some(target),
        })?;
        Ok(deepview_mpi::render(&made.mpi, target).to_rgb())
    }

    fn last_mpi(&self) -> Option<(&Mpi, Option<&PlanesRule>)> {
        self.last
            .as_ref()
            .map(|(_, m)| (&m.mpi, m.planes.as_ref().map(|c| &c.rule)))
    }
}
