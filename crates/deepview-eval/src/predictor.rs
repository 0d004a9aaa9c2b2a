//! What the eval runner scores: an [`MpiMethod`]'s MPI rendered into the target, so `eval` scores exactly the
//! MPI that `infer` writes.

use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_methods::{MadeMpi, MethodError, MethodEvent, MpiMethod, MpiRequest};
use deepview_mpi::{CompactOptions, Mpi, PlanesRule};

/// The request an MPI was made for: input cameras, their ids, the bounds and, when the method uses it,
/// the target camera.
type RequestKey = (Vec<Camera>, Vec<usize>, (f64, f64), Option<Camera>);

/// An [`MpiMethod`] scored by the eval runner: the MPI rendered into the target. The last MPI is kept, so
/// targets that share inputs (and, for `nearest`, the target) reuse it.
pub struct MpiPredictor<'e> {
    method: Box<dyn MpiMethod + 'e>,
    events: Box<dyn FnMut(MethodEvent<'_>) + 'e>,
    last: Option<(RequestKey, MadeMpi)>,
    compact: Option<CompactOptions>,
    /// Why the last prediction shows little of its MPI ([`deepview_mpi::view_warning`]).
    warning: Option<String>,
}

impl<'e> MpiPredictor<'e> {
    /// Score `method`, reporting its events to `events`.
    pub fn new(method: Box<dyn MpiMethod + 'e>, events: impl FnMut(MethodEvent<'_>) + 'e) -> Self {
        Self {
            method,
            events: Box::new(events),
            last: None,
            compact: None,
            warning: None,
        }
    }

    /// Compact every MPI the method makes before it is rendered and kept ([`deepview_mpi::compact`]):
    /// what `deepview compact` does to an `infer` output, scored.
    pub fn compacted(mut self, options: CompactOptions) -> Self {
        self.compact = Some(options);
        self
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
    pub fn mpi(&mut self, request: &MpiRequest<'_>) -> Result<&MadeMpi, MethodError> {
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
            let mut made = self.method.make_mpi(request, &mut *self.events)?;
            if let Some(options) = &self.compact {
                made.mpi = deepview_mpi::compact(&made.mpi, options).mpi;
            }
            self.last = Some((key, made));
        }
        Ok(&self.last.as_ref().expect("just made").1)
    }

    /// The method's name.
    pub fn name(&self) -> &str {
        self.method.name()
    }

    /// The target's image: the MPI of `inputs` (dataset indices `ids`) rendered into `target`, RGB.
    pub fn predict(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        ids: &[usize],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, MethodError> {
        let made = self.mpi(&MpiRequest {
            inputs,
            ids,
            near_far,
            toward: Some(target),
        })?;
        let rgba = deepview_mpi::render(&made.mpi, target);
        let warning = deepview_mpi::view_warning(&made.mpi, target, deepview_mpi::coverage(&rgba));
        self.warning = warning;
        Ok(rgba.to_rgb())
    }

    /// Why the last prediction shows little of its MPI (a target behind the planes, or one the MPI
    /// hardly covers), where it does.
    pub fn last_warning(&self) -> Option<&str> {
        self.warning.as_deref()
    }

    /// The MPI the last prediction rendered and how its planes were chosen.
    pub fn last_mpi(&self) -> Option<(&Mpi, Option<&PlanesRule>)> {
        self.last
            .as_ref()
            .map(|(_, m)| (&m.mpi, m.planes.as_ref().map(|c| &c.rule)))
    }
}
