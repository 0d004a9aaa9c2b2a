//! Tiling: the tiles of the MPI, and per tile what each view contributes (the view-image crop its
//! samples need, and the MPI sub-window whose renders reach that crop).

use crate::forward::{Hom, crop_source, invert, mpi_to_view_homographies};
use deepview_geometry::Camera;
use deepview_image::ImageF32;

/// A pixel rectangle `(x0, y0, w, h)`.
pub(super) type Rect = (usize, usize, usize, usize);

/// The per-view geometry of an inference problem.
pub(super) struct Geometry {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) d: usize,
    /// `[view][plane]`: MPI pixels -> view pixels.
    pub(super) homs: Vec<Vec<Hom>>,
    /// `(width, height)` of each view.
    pub(super) view_sizes: Vec<(usize, usize)>,
}

/// What one view contributes to a tile: the view-image crop and the MPI sub-window rendered into the
/// crop (update nets only; the region itself for the init net).
pub(super) struct ViewWindow {
    pub(super) crop: Rect,
    pub(super) sub: Rect,
}

impl Geometry {
    pub(super) fn new(views: &[(ImageF32, Camera)], reference: &Camera, depths: &[f64]) -> Self {
        Self {
            w: reference.width as usize,
            h: reference.height as usize,
            d: depths.len(),
            homs: mpi_to_view_homographies(reference, views.iter().map(|(_, c)| c), depths),
            view_sizes: views
                .iter()
                .map(|(img, _)| (img.width as usize, img.height as usize))
                .collect(),
        }
    }

    pub(super) fn tiles(&self, tile: usize) -> Vec<Rect> {
        let (w, h) = (self.w, self.h);
        (0..h)
            .step_by(tile)
            .flat_map(|y| {
                (0..w)
                    .step_by(tile)
                    .map(move |x| (x, y, tile.min(w - x), tile.min(h - y)))
            })
            .collect()
    }

    /// The tile grown by `margin`, clamped to the MPI.
    pub(super) fn region(&self, tile: Rect, margin: usize) -> Rect {
        let (tx, ty, tw, th) = tile;
        let (x0, y0) = (tx.saturating_sub(margin), ty.saturating_sub(margin));
        let (x1, y1) = (
            (tx + tw + margin).min(self.w),
            (ty + th + margin).min(self.h),
        );
        (x0, y0, x1 - x0, y1 - y0)
    }

    pub(super) fn view_window(&self, k: usize, region: Rect, with_sub: bool) -> ViewWindow {
        let (vw, vh) = self.view_sizes[k];
        let (crop, sees) = view_crop(&self.homs[k], region, vw, vh);
        // A view that no sample of the region sees needs no render: any window will do.
        let sub = if with_sub && sees {
            let mpi_to_crop: Vec<Hom> = self.homs[k]
                .iter()
                .map(|hm| crop_source(hm, crop.0 as f64, crop.1 as f64))
                .collect();
            mpi_window(&mpi_to_crop, crop.2, crop.3, self.w, self.h, region)
        } else {
            region
        };
        ViewWindow { crop, sub }
    }
}

/// The view-image crop `(x0, y0, w, h)` that every sample of MPI region `region` (all planes) needs, and
/// whether any sample can fall inside the view (if not, the crop is a 1x1 placeholder no sample reaches).
fn view_crop(homs: &[Hom], region: Rect, vw: usize, vh: usize) -> (Rect, bool) {
    let (rx, ry, rw, rh) = region;
    let corners = [(rx, ry), (rx + rw, ry), (rx, ry + rh), (rx + rw, ry + rh)]
        .map(|(u, v)| (u as f64, v as f64));
    match bounding_box(homs, &corners) {
        None => ((0, 0, vw, vh), true),
        Some(b) => match grown_box(b, vw, vh) {
            Some(crop) => (crop, true),
            None => ((0, 0, vw.min(1), vh.min(1)), false),
        },
    }
}

/// The bounding box `(x0, y0, x1, y1)` of the images of `corners` under every homography, or `None` when
/// a corner maps to infinity or behind the camera (the image of the rectangle is then unbounded).
fn bounding_box(homs: &[Hom], corners: &[(f64, f64); 4]) -> Option<(f64, f64, f64, f64)> {
    let (mut x0, mut y0, mut x1, mut y1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for h in homs {
        for &(u, v) in corners {
            let z = h[6] * u + h[7] * v + h[8];
            let x = (h[0] * u + h[1] * v + h[2]) / z;
            let y = (h[3] * u + h[4] * v + h[5]) / z;
            if !(z > 0.0 && x.is_finite() && y.is_finite()) {
                return None;
            }
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        }
    }
    Some((x0, y0, x1, y1))
}

/// The texels `[floor(x0) - 2, ceil(x1) + 2)` (and the same in y) clamped to a `w x h` image, or `None`
/// when that is empty. A bilinear sample at continuous `s` reads texels `floor(s - 0.5)` and the next one,
/// so for `s` in `[x0, x1]` both lie within one texel of the box; the second texel of slack covers the
/// f32 rounding of the samples' positions.
fn grown_box(b: (f64, f64, f64, f64), w: usize, h: usize) -> Option<Rect> {
    let (x0, y0, x1, y1) = b;
    let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
    let (cx0, cx1) = (clamp(x0.floor() - 2.0, w), clamp(x1.ceil() + 2.0, w));
    let (cy0, cy1) = (clamp(y0.floor() - 2.0, h), clamp(y1.ceil() + 2.0, h));
    (cx1 > cx0 && cy1 > cy0).then_some((cx0, cy0, cx1 - cx0, cy1 - cy0))
}

/// The sub-window of a `w x h` MPI holding every texel that a render into a `cw x ch` view crop samples
/// on any plane (`mpi_to_crop[d]`: MPI pixels -> crop pixels), joined with `region` (which the gradient
/// components are computed on, relative to the sub-window). Exact: a sample inside the MPI lies in the
/// crop's back-projected bounding box, hence inside the window with its bilinear taps; a sample outside
/// the MPI is outside the window, which is clamped to the MPI; and the window's edge clamping only
/// differs from the MPI's where no tap reaches it.
fn mpi_window(mpi_to_crop: &[Hom], cw: usize, ch: usize, w: usize, h: usize, region: Rect) -> Rect {
    let inverse: Vec<Hom> = mpi_to_crop.iter().map(invert).collect();
    let corners = [(0, 0), (cw, 0), (0, ch), (cw, ch)].map(|(u, v)| (u as f64, v as f64));
    let Some(b) = bounding_box(&inverse, &corners) else {
        return (0, 0, w, h);
    };
    let Some((x0, y0, sw, sh)) = grown_box(b, w, h) else {
        return region;
    };
    let (rx, ry, rw, rh) = region;
    let (x1, y1) = ((x0 + sw).max(rx + rw), (y0 + sh).max(ry + rh));
    let (x0, y0) = (x0.min(rx), y0.min(ry));
    (x0, y0, x1 - x0, y1 - y0)
}
