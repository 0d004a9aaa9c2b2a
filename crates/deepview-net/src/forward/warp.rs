//! Homography warps of plane stacks: the bilinear taps ([`WarpTable`]) applied to tensors and the 3x3
//! homography helpers.

use super::taps::{Hom, WarpTable};
use burn::tensor::{Device, Int, Tensor, TensorData};

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

impl WarpTable {
    /// Warp `src` `[S, C, src_h, src_w]` -> `[planes, C, out_h, out_w]`. `S` is `planes` (plane `d` is
    /// warped by homography `d`) or 1 (the one source is broadcast to every plane: a plane sweep).
    /// On the CPU one operation with its own backward ([`crate::cpu::ops::KernelOps::warp`]), on a GPU
    /// our kernel ([`crate::gpu`]: one dispatch, i32 taps; a gather over the transposed taps as its
    /// backward), elsewhere (`--engine burn`) [`Self::apply_burn`].
    pub fn apply(&self, src: Tensor<4>) -> Tensor<4> {
        let device = src.device();
        if crate::cpu::ops::fast_device(&device) {
            self.check_source(&src);
            return crate::cpu::ops::warp(src, std::sync::Arc::new(self.clone()));
        }
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if crate::gpu::gpu_kernels(&device) {
            self.check_source(&src);
            return crate::gpu::warp(self, src);
        }
        self.apply_burn(src)
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
        let (idx, w) = self.taps();
        let n = w.len() / 4;
        let (d, oh, ow) = (self.planes, self.out_h, self.out_w);
        if n == 0 || sh * sw == 0 {
            return Tensor::zeros([d, c, oh, ow], &device);
        }
        let per_plane = oh * ow;
        let plane_len = (sh * sw) as i64;
        let idx: Vec<i64> = if s == 1 {
            idx.to_vec()
        } else {
            idx.iter()
                .enumerate()
                .map(|(i, &v)| v + ((i % n) / per_plane) as i64 * plane_len)
                .collect()
        };
        let idx = Tensor::<1, Int>::from_data(TensorData::new(idx, [4 * n]), &device);
        let w = Tensor::<3>::from_data(TensorData::new(w.to_vec(), [4, n, 1]), &device);
        let flat = src.permute([0, 2, 3, 1]).reshape([s * sh * sw, c]);
        let taps = flat.select(0, idx).reshape([4, n, c]);
        let out = (taps * w).sum_dim(0).reshape([d, oh, ow, c]);
        out.permute([0, 3, 1, 2])
    }

    /// Validity `[planes, 1, out_h, out_w]`: 1 where the sample falls inside the source.
    pub fn valid(&self, device: &Device) -> Tensor<4> {
        Tensor::from_data(
            TensorData::new(
                self.valid_data().to_vec(),
                [self.planes, 1, self.out_h, self.out_w],
            ),
            device,
        )
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
