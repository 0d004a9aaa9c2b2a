//! Homography warps of plane stacks: the bilinear taps ([`WarpTable`]) and the 3x3 homography helpers.

use burn::tensor::{Device, Int, Tensor, TensorData};
use std::sync::Arc;

/// A row-major 3x3 homography (f64), output pixels -> source pixels.
pub type Hom = [f64; 9];

/// The plane homographies from the reference camera's pixels to each camera's pixels at every depth,
/// `[camera][depth]` (the `mpi_to_view` of [`crate::network::ModelInputs`]).
pub fn mpi_to_view_homographies<'a>(
    reference: &deepview_geometry::Camera,
    cameras: impl IntoIterator<Item = &'a deepview_geometry::Camera>,
    depths: &[f64],
) -> Vec<Vec<Hom>> {
    cameras
        .into_iter()
        .map(|cam| {
            depths
                .iter()
                .map(|&z| deepview_geometry::plane_homography(reference, cam, z).to_row_major())
                .collect()
        })
        .collect()
}

/// Precomputed bilinear taps of `planes` homography warps from a `src_w x src_h` source to an
/// `out_w x out_h` output.
#[derive(Clone, Debug)]
pub struct WarpTable {
    pub planes: usize,
    pub src_w: usize,
    pub src_h: usize,
    pub out_w: usize,
    pub out_h: usize,
    /// `[4][planes * out_h * out_w]` texel indices within one source plane (`y * src_w + x`). Shared
    /// (as the weights and the mask), so that a clone is cheap: [`Self::apply`] hands one to the CPU
    /// operation, which keeps it for the backward.
    idx: Arc<[i64]>,
    /// `[4][planes * out_h * out_w]` bilinear weights (0 for invalid samples).
    w: Arc<[f32]>,
    /// `[planes * out_h * out_w]`: 1 where the sample is inside the source.
    valid: Arc<[f32]>,
}

impl WarpTable {
    /// Taps of `homs.len()` warps (one per plane). Empty sources or outputs are allowed (all invalid).
    pub fn new(homs: &[Hom], src_w: usize, src_h: usize, out_w: usize, out_h: usize) -> Self {
        #[cfg(target_arch = "x86_64")]
        if deepview_kernels::simd() {
            // SAFETY: the CPU has AVX2 and FMA (checked): the same code with hardware `fma`/`floor`
            // instead of libm calls (identical results: `mul_add` is exact either way).
            return unsafe { Self::new_fma(homs, src_w, src_h, out_w, out_h) };
        }
        Self::new_portable(homs, src_w, src_h, out_w, out_h)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn new_fma(
        homs: &[Hom],
        src_w: usize,
        src_h: usize,
        out_w: usize,
        out_h: usize,
    ) -> Self {
        Self::new_portable(homs, src_w, src_h, out_w, out_h)
    }

    #[inline(always)]
    fn new_portable(homs: &[Hom], src_w: usize, src_h: usize, out_w: usize, out_h: usize) -> Self {
        let n = homs.len() * out_w * out_h;
        let mut idx = vec![0i64; 4 * n];
        let mut w = vec![0f32; 4 * n];
        let mut valid = vec![0f32; n];
        let (wf, hf) = (src_w as f32, src_h as f32);
        let (wmax, hmax) = (src_w as i32 - 1, src_h as i32 - 1);
        for (d, h) in homs.iter().enumerate() {
            let a = [h[0] as f32, h[3] as f32, h[6] as f32];
            for y in 0..out_h {
                let v = y as f64 + 0.5;
                let b = [
                    (h[1] * v + h[2]) as f32,
                    (h[4] * v + h[5]) as f32,
                    (h[7] * v + h[8]) as f32,
                ];
                for x in 0..out_w {
                    let o = (d * out_h + y) * out_w + x;
                    let u = x as f32 + 0.5;
                    let wn = a[2].mul_add(u, b[2]);
                    if wn <= 0.0 || src_w == 0 || src_h == 0 {
                        continue;
                    }
                    let inv = 1.0 / wn;
                    let sx = a[0].mul_add(u, b[0]) * inv;
                    let sy = a[1].mul_add(u, b[1]) * inv;
                    if !(sx >= 0.0 && sx <= wf && sy >= 0.0 && sy <= hf) {
                        continue;
                    }
                    let (fx, fy) = (sx - 0.5, sy - 0.5);
                    let (x0, y0) = (fx.floor(), fy.floor());
                    let (tx, ty) = (fx - x0, fy - y0);
                    let (x0, y0) = (x0 as i32, y0 as i32);
                    let xa = x0.clamp(0, wmax) as i64;
                    let xb = (x0 + 1).clamp(0, wmax) as i64;
                    let ya = y0.clamp(0, hmax) as i64 * src_w as i64;
                    let yb = (y0 + 1).clamp(0, hmax) as i64 * src_w as i64;
                    let taps = [ya + xa, ya + xb, yb + xa, yb + xb];
                    let ws = [
                        (1.0 - tx) * (1.0 - ty),
                        tx * (1.0 - ty),
                        (1.0 - tx) * ty,
                        tx * ty,
                    ];
                    for t in 0..4 {
                        idx[t * n + o] = taps[t];
                        w[t * n + o] = ws[t];
                    }
                    valid[o] = 1.0;
                }
            }
        }
        Self {
            planes: homs.len(),
            src_w,
            src_h,
            out_w,
            out_h,
            idx: idx.into(),
            w: w.into(),
            valid: valid.into(),
        }
    }

    /// Warp `src` `[S, C, src_h, src_w]` -> `[planes, C, out_h, out_w]`. `S` is `planes` (plane `d` is
    /// warped by homography `d`) or 1 (the one source is broadcast to every plane: a plane sweep).
    /// On the CPU one operation with its own backward ([`crate::kernels::KernelOps::warp`]), elsewhere
    /// [`Self::apply_burn`].
    pub fn apply(&self, src: Tensor<4>) -> Tensor<4> {
        if crate::kernels::fast_device(&src.device()) {
            self.check_source(&src);
            return crate::kernels::warp(src, std::sync::Arc::new(self.clone()));
        }
        self.apply_burn(src)
    }

    /// The bilinear taps: `[4][planes * out_h * out_w]` source texel indices within one plane and
    /// weights (0 for invalid samples).
    pub fn taps(&self) -> (&[i64], &[f32]) {
        (&self.idx, &self.w)
    }

    fn check_source(&self, src: &Tensor<4>) {
        let [s, _, sh, sw] = src.dims();
        assert_eq!(
            (sh, sw),
            (self.src_h, self.src_w),
            "warp source size mismatch"
        );
        assert!(
            s == self.planes || s == 1,
            "warp source has {s} planes, table has {}",
            self.planes
        );
    }

    /// [`Self::apply`] with burn's tensor ops (a `select` gather and a weighted sum; its backward a
    /// scatter-add): any device, and the reference of the CPU operation.
    pub fn apply_burn(&self, src: Tensor<4>) -> Tensor<4> {
        self.check_source(&src);
        let [s, c, sh, sw] = src.dims();
        let device = src.device();
        let n = self.valid.len();
        let (d, oh, ow) = (self.planes, self.out_h, self.out_w);
        if n == 0 || sh * sw == 0 {
            return Tensor::zeros([d, c, oh, ow], &device);
        }
        let per_plane = oh * ow;
        let plane_len = (sh * sw) as i64;
        let idx: Vec<i64> = if s == 1 {
            self.idx.to_vec()
        } else {
            self.idx
                .iter()
                .enumerate()
                .map(|(i, &v)| v + ((i % n) / per_plane) as i64 * plane_len)
                .collect()
        };
        let idx = Tensor::<1, Int>::from_data(TensorData::new(idx, [4 * n]), &device);
        let w = Tensor::<3>::from_data(TensorData::new(self.w.to_vec(), [4, n, 1]), &device);
        let flat = src.permute([0, 2, 3, 1]).reshape([s * sh * sw, c]);
        let taps = flat.select(0, idx).reshape([4, n, c]);
        let out = (taps * w).sum_dim(0).reshape([d, oh, ow, c]);
        out.permute([0, 3, 1, 2])
    }

    /// Validity `[planes, 1, out_h, out_w]`: 1 where the sample falls inside the source.
    pub fn valid(&self, device: &Device) -> Tensor<4> {
        Tensor::from_data(
            TensorData::new(
                self.valid.to_vec(),
                [self.planes, 1, self.out_h, self.out_w],
            ),
            device,
        )
    }

    /// The validity mask as plain data, `[planes][out_h][out_w]`.
    pub fn valid_data(&self) -> &[f32] {
        &self.valid
    }
}

/// Invert a row-major 3x3 matrix (f64). Singular matrices give non-finite entries (all samples invalid).
pub fn invert(h: &Hom) -> Hom {
    let m = glam::DMat3::from_cols_array(h).transpose();
    let inv = m.inverse().transpose();
    inv.to_cols_array()
}

/// `a * b` for row-major 3x3 matrices.
pub fn mul(a: &Hom, b: &Hom) -> Hom {
    let mut out = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[r * 3 + c] = (0..3).map(|k| a[r * 3 + k] * b[k * 3 + c]).sum();
        }
    }
    out
}

/// The homography of the same map after moving the output origin to output pixel `(x0, y0)`
/// (i.e. `H * translate(x0, y0)`): use it for a crop of the output.
pub fn crop_output(h: &Hom, x0: f64, y0: f64) -> Hom {
    mul(h, &[1.0, 0.0, x0, 0.0, 1.0, y0, 0.0, 0.0, 1.0])
}

/// The homography of the same map after moving the source origin to source pixel `(x0, y0)`
/// (i.e. `translate(-x0, -y0) * H`): use it for a crop of the source.
pub fn crop_source(h: &Hom, x0: f64, y0: f64) -> Hom {
    mul(&[1.0, 0.0, -x0, 0.0, 1.0, -y0, 0.0, 0.0, 1.0], h)
}

/// Warp every plane of `planes` `[D, C, h_src, w_src]` by its homography (`homographies[d]`, row-major
/// f32, output pixels -> source pixels) into `[D, C, out_h, out_w]`, with the sampling rule above.
pub fn warp_planes(
    planes: Tensor<4>,
    homographies: &[[f32; 9]],
    out_h: usize,
    out_w: usize,
) -> Tensor<4> {
    let [_, _, sh, sw] = planes.dims();
    let homs: Vec<Hom> = homographies.iter().map(|h| h.map(|v| v as f64)).collect();
    WarpTable::new(&homs, sw, sh, out_w, out_h).apply(planes)
}

/// The same warp with `grid_sample_2d` (bilinear, `align_corners = false`, border padding) and an explicit
/// in-bounds mask: identical results, kept for benchmarking (its backward is much slower on `flex`).
pub fn warp_planes_grid_sample(
    planes: Tensor<4>,
    homographies: &[[f32; 9]],
    out_h: usize,
    out_w: usize,
) -> Tensor<4> {
    use burn::tensor::ops::{GridSampleOptions, GridSamplePaddingMode, InterpolateMode};
    let [d, _, sh, sw] = planes.dims();
    let device = planes.device();
    let homs: Vec<Hom> = homographies.iter().map(|h| h.map(|v| v as f64)).collect();
    let table = WarpTable::new(&homs, sw, sh, out_w, out_h);
    let mut grid = vec![0f32; d * out_h * out_w * 2];
    for (p, h) in homographies.iter().enumerate() {
        let a = [h[0], h[3], h[6]];
        for y in 0..out_h {
            let v = y as f64 + 0.5;
            let hh = homs[p];
            let b = [
                (hh[1] * v + hh[2]) as f32,
                (hh[4] * v + hh[5]) as f32,
                (hh[7] * v + hh[8]) as f32,
            ];
            for x in 0..out_w {
                let u = x as f32 + 0.5;
                let inv = 1.0 / a[2].mul_add(u, b[2]);
                let sx = a[0].mul_add(u, b[0]) * inv;
                let sy = a[1].mul_add(u, b[1]) * inv;
                let o = ((p * out_h + y) * out_w + x) * 2;
                // align_corners = false: normalised -1..1 spans the outer texel edges 0..W.
                let gx = if sx.is_finite() {
                    2.0 * sx / sw as f32 - 1.0
                } else {
                    -2.0
                };
                let gy = if sy.is_finite() {
                    2.0 * sy / sh as f32 - 1.0
                } else {
                    -2.0
                };
                grid[o] = gx;
                grid[o + 1] = gy;
            }
        }
    }
    let grid = Tensor::<4>::from_data(TensorData::new(grid, [d, out_h, out_w, 2]), &device);
    let opts = GridSampleOptions::new(InterpolateMode::Bilinear)
        .with_padding_mode(GridSamplePaddingMode::Border)
        .with_align_corners(false);
    planes.grid_sample_2d(grid, opts) * table.valid(&device)
}
