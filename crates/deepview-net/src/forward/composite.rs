//! Over-compositing with net transmittance `T` and accumulated over `A`, renders into views, plane sweep
//! volumes, the gradient components, and images as tensors.

use super::taps::{Frames, Hom, WarpTable};
use super::warp::{crop_output, invert};
use burn::tensor::{Device, Tensor, TensorData};

/// The over-composite of `rgba` `[D, 4, h, w]` (premultiplied, back to front) and its per-plane gradient
/// components.
#[derive(Clone, Debug)]
pub struct Composite {
    /// `[3, h, w]`: `sum_d c_d T_d`.
    pub render: Tensor<3>,
    /// `[D, 1, h, w]`: net transmittance `T_d = prod_{i>d} (1 - a_i)`.
    pub transmittance: Tensor<4>,
    /// `[D, 3, h, w]`: accumulated over `A_d = sum_{i<d} c_i prod_{i<j<d} (1 - a_j)`.
    pub accumulated: Tensor<4>,
}

impl Composite {
    /// From one kernel's output `[D + 1, 4, h, w]`: planes `..D` hold `A` (3) and `T` (1), plane `D` the
    /// render (3).
    ///
    /// Each part is one slice of it (under autodiff on a GPU each slice's backward is a fill and a
    /// slice-assign launch: a slice per axis would double them).
    fn from_packed(out: Tensor<4>) -> Self {
        let [d1, _, h, w] = out.dims();
        let d = d1 - 1;
        Self {
            render: out.clone().slice([d..d1, 0..3]).reshape([3, h, w]),
            transmittance: out.clone().slice([0..d, 3..4]),
            accumulated: out.slice([0..d, 0..3]),
        }
    }
}

/// Over-composite `rgba` `[D, 4, h, w]` (premultiplied colour, plane 0 the farthest). A loop over planes
/// (no division, so alpha = 1 is safe); `d render / d c_d = T_d` and `d render / d a_d = -A_d T_d`.
pub fn composite(rgba: Tensor<4>) -> Composite {
    if crate::cpu::ops::fast_device(&rgba.device()) {
        return Composite::from_packed(crate::cpu::ops::composite(rgba));
    }
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if crate::gpu::gpu_kernels(&rgba.device()) {
        return Composite::from_packed(crate::gpu::composite(rgba));
    }
    composite_scan(rgba)
}

/// [`composite`] as parallel scans over the planes (Hillis-Steele: `ceil(log2 D)` steps, each a few ops on
/// the whole `[D, ...]` tensor), for devices where each op is a dispatch (GPUs): about 60 ops forward for
/// 32 planes where [`composite_burn`]'s loop takes ~200, and the same again in the backward. Products
/// only (no division, alpha = 1 is safe); the sums associate differently from the loop (f32 rounding).
///
/// Accumulated over: `A_{p+1} = A_p (1 - a_p) + c_p` is the composition of the affine maps
/// `x -> m_p x + c_p` (`m = 1 - a`), scanned as pairs `(M, B)` with `(M2, B2) o (M1, B1) = (M2 M1,
/// M2 B1 + B2)`; then `A_p = B_{p-1}` and the render is `B_{D-1}`. Transmittance `T_p = prod_{i>p} m_i`:
/// a reverse product scan, shifted by one plane.
pub fn composite_scan(rgba: Tensor<4>) -> Composite {
    let [d, _, h, w] = rgba.dims();
    let device = rgba.device();
    let mut b = rgba.clone().narrow(1, 0, 3);
    let m0 = rgba.narrow(1, 3, 1).neg().add_scalar(1.0);
    let mut m = m0.clone();
    // Inclusive reverse products, P_p = prod_{i >= p} m_i.
    let mut p = m0;
    let mut k = 1;
    while k < d {
        let ones = Tensor::<4>::ones([k, 1, h, w], &device);
        let zeros = Tensor::<4>::zeros([k, 3, h, w], &device);
        let m_prev = Tensor::cat(vec![ones.clone(), m.clone().narrow(0, 0, d - k)], 0);
        let b_prev = Tensor::cat(vec![zeros, b.clone().narrow(0, 0, d - k)], 0);
        b = m.clone() * b_prev + b;
        m = m * m_prev;
        let p_next = Tensor::cat(vec![p.clone().narrow(0, k, d - k), ones], 0);
        p = p * p_next;
        k *= 2;
    }
    let render = b.clone().narrow(0, d - 1, 1).reshape([3, h, w]);
    let (zero, one) = (
        Tensor::zeros([1, 3, h, w], &device),
        Tensor::ones([1, 1, h, w], &device),
    );
    let (accumulated, transmittance) = if d == 1 {
        (zero, one)
    } else {
        (
            Tensor::cat(vec![zero, b.narrow(0, 0, d - 1)], 0),
            Tensor::cat(vec![p.narrow(0, 1, d - 1), one], 0),
        )
    };
    Composite {
        render,
        transmittance,
        accumulated,
    }
}

/// [`composite`] with burn's tensor ops as a loop over the planes (any device; the reference of the CPU
/// operation and of [`composite_scan`]).
pub fn composite_burn(rgba: Tensor<4>) -> Composite {
    let [d, _, h, w] = rgba.dims();
    let device = rgba.device();
    let colour = rgba.clone().narrow(1, 0, 3);
    let one_minus = rgba.narrow(1, 3, 1).neg().add_scalar(1.0);
    // Accumulated over, back to front.
    let mut acc: Vec<Tensor<4>> = Vec::with_capacity(d);
    let mut a = Tensor::<4>::zeros([1, 3, h, w], &device);
    for p in 0..d {
        acc.push(a.clone());
        a = a * one_minus.clone().narrow(0, p, 1) + colour.clone().narrow(0, p, 1);
    }
    let render = a.reshape([3, h, w]);
    // Transmittance, front to back.
    let mut trans: Vec<Tensor<4>> = vec![Tensor::zeros([1, 1, 1, 1], &device); d];
    let mut t = Tensor::<4>::ones([1, 1, h, w], &device);
    for p in (0..d).rev() {
        trans[p] = t.clone();
        if p > 0 {
            t = t * one_minus.clone().narrow(0, p, 1);
        }
    }
    Composite {
        render,
        transmittance: Tensor::cat(trans, 0),
        accumulated: Tensor::cat(acc, 0),
    }
}

/// Render an MPI `rgba` `[D, 4, H, W]` into a view: `view_to_mpi[d]` maps view pixels to MPI pixels of
/// plane `d`; the output is `out_w x out_h` view pixels. Returns the composite with its `T` and `A`.
pub fn render_view(rgba: Tensor<4>, view_to_mpi: &[Hom], out_h: usize, out_w: usize) -> Composite {
    let [_, _, h, w] = rgba.dims();
    render_view_framed(rgba, view_to_mpi, Frames::whole(w, h), out_h, out_w)
}

/// [`render_view`] where `rgba` is a window of the MPI and the output a crop of the view ([`Frames`]);
/// `view_to_mpi` maps whole-view pixels to whole-MPI pixels.
pub fn render_view_framed(
    rgba: Tensor<4>,
    view_to_mpi: &[Hom],
    frames: Frames,
    out_h: usize,
    out_w: usize,
) -> Composite {
    composite(warp_to_view(rgba, view_to_mpi, frames, out_h, out_w))
}

/// `rgba`'s planes warped into the view as [`render_view_framed`] renders them, before compositing.
fn warp_to_view(
    rgba: Tensor<4>,
    view_to_mpi: &[Hom],
    frames: Frames,
    out_h: usize,
    out_w: usize,
) -> Tensor<4> {
    let [_, _, h, w] = rgba.dims();
    WarpTable::new_framed(view_to_mpi, frames, w, h, out_w, out_h).apply(rgba)
}

/// The plane sweep volume of `image` `[3, hv, wv]` on a `w x h` MPI window: `mpi_to_view[d]` maps MPI
/// window pixels to view pixels. Returns `[D, 4, h, w]`: RGB and a validity channel (1 where the sample
/// falls inside the image).
pub fn plane_sweep_volume(image: Tensor<3>, mpi_to_view: &[Hom], h: usize, w: usize) -> Tensor<4> {
    let [_, hv, wv] = image.dims();
    plane_sweep_volume_framed(image, mpi_to_view, Frames::whole(wv, hv), h, w)
}

/// [`plane_sweep_volume`] where `image` is a crop of the view and the `w x h` output a window of the
/// MPI ([`Frames`]); `mpi_to_view` maps whole-MPI pixels to whole-view pixels.
pub fn plane_sweep_volume_framed(
    image: Tensor<3>,
    mpi_to_view: &[Hom],
    frames: Frames,
    h: usize,
    w: usize,
) -> Tensor<4> {
    let [c, hv, wv] = image.dims();
    let table = WarpTable::new_framed(mpi_to_view, frames, wv, hv, w, h);
    let device = image.device();
    let image = image.reshape([1, c, hv, wv]);
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if crate::gpu::gpu_kernels(&device) {
        return crate::gpu::sweep(&table, image);
    }
    let psv = table.apply(image);
    Tensor::cat(vec![psv, table.valid(&device)], 1)
}

/// Number of channels of [`gradient_components`]: `[I (3), R (3), A (3), T (1), validity (1)]`.
pub const GRADIENT_CHANNELS: usize = 11;

/// The gradient components of one view on an MPI region, `[D, 11, h, w]`, channels
/// `[I_k (3), R_k (3), A_k (3), T_k (1), validity (1)]`, all inverse-warped into MPI space.
///
/// - `rgba` `[D, 4, Hm, Wm]`: the MPI (premultiplied) that is rendered into the view; its pixel frame is
///   the one `mpi_to_view` starts from;
/// - `image` `[3, hv, wv]`: the view's image (or a crop of it, with `mpi_to_view` mapping to crop pixels);
/// - `region = (x0, y0, w, h)`: the MPI pixels (in `rgba`'s frame) where the components are wanted.
///
/// `R_k`, `A_k`, `T_k` are computed at every pixel of `image` from the whole of `rgba` (outside `rgba`
/// the MPI is transparent).
pub fn gradient_components(
    rgba: Tensor<4>,
    image: Tensor<3>,
    mpi_to_view: &[Hom],
    region: (usize, usize, usize, usize),
) -> Tensor<4> {
    let [_, hv, wv] = image.dims();
    let [_, _, mh, mw] = rgba.dims();
    let view_to_mpi: Vec<Hom> = mpi_to_view.iter().map(invert).collect();
    let (x0, y0, w, h) = region;
    let region_homs: Vec<Hom> = mpi_to_view
        .iter()
        .map(|m| crop_output(m, x0 as f64, y0 as f64))
        .collect();
    let table = WarpTable::new(&region_homs, wv, hv, w, h);
    components_of_render(rgba, &view_to_mpi, Frames::whole(mw, mh), image, &table)
}

/// A window of an MPI and a crop of a view, placed in the whole MPI (`mpi_size`) and view (`view_size`).
#[derive(Clone, Copy, Debug)]
pub struct Crops {
    /// Origin of the MPI window in the MPI.
    pub window: (usize, usize),
    pub mpi_size: (usize, usize),
    /// Origin of the view crop in the view.
    pub crop: (usize, usize),
    pub view_size: (usize, usize),
}

/// [`gradient_components`] from a window `rgba` of the MPI and a crop `image` of the view ([`Crops`]),
/// with `mpi_to_view` mapping whole-MPI pixels to whole-view pixels and `region` in whole-MPI pixels:
/// bit for bit the region of the whole computation when the window holds every texel that a render of
/// the crop samples and the crop every texel the region's samples read ([`Frames`]).
pub fn gradient_components_framed(
    rgba: Tensor<4>,
    image: Tensor<3>,
    mpi_to_view: &[Hom],
    crops: Crops,
    region: (usize, usize, usize, usize),
) -> Tensor<4> {
    let [_, hv, wv] = image.dims();
    let view_to_mpi: Vec<Hom> = mpi_to_view.iter().map(invert).collect();
    let render = Frames {
        src_origin: crops.window,
        src_full: crops.mpi_size,
        out_origin: crops.crop,
    };
    let (x0, y0, w, h) = region;
    let sample = Frames {
        src_origin: crops.crop,
        src_full: crops.view_size,
        out_origin: (x0, y0),
    };
    let table = WarpTable::new_framed(mpi_to_view, sample, wv, hv, w, h);
    components_of_render(rgba, &view_to_mpi, render, image, &table)
}

/// The gradient components of `image` and the render of `rgba` into it (`view_to_mpi`, `frames`: as
/// [`render_view_framed`]), sampled by `table`. On a cubecl device the components are warped straight from
/// the composite kernel's packed output: the render, `A` and `T` are never sliced out of it (each slice
/// of a tracked tensor is a dispatch there).
fn components_of_render(
    rgba: Tensor<4>,
    view_to_mpi: &[Hom],
    frames: Frames,
    image: Tensor<3>,
    table: &WarpTable,
) -> Tensor<4> {
    let [_, hv, wv] = image.dims();
    let warped = warp_to_view(rgba, view_to_mpi, frames, hv, wv);
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if crate::gpu::gpu_kernels(&warped.device()) {
        let packed = crate::gpu::composite(warped);
        return crate::gpu::components(table, image.reshape([1, 3, hv, wv]), packed);
    }
    components_from(image, composite(warped), table)
}

/// The gradient components of a view image and its render, sampled by `table`.
fn components_from(image: Tensor<3>, comp: Composite, table: &WarpTable) -> Tensor<4> {
    let [_, hv, wv] = image.dims();
    let images = Tensor::cat(
        vec![
            image.reshape([1, 3, hv, wv]),
            comp.render.reshape([1, 3, hv, wv]),
        ],
        1,
    );
    let planes = Tensor::cat(vec![comp.accumulated, comp.transmittance], 1);
    let device = planes.device();
    Tensor::cat(
        vec![
            table.apply(images),
            table.apply(planes),
            table.valid(&device),
        ],
        1,
    )
}

/// Tensor `[3, h, w]` from an interleaved RGB(A...) image (first three channels).
pub fn image_tensor(
    data: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    device: &Device,
) -> Tensor<3> {
    let mut out = vec![0f32; 3 * width * height];
    for p in 0..width * height {
        for c in 0..3 {
            out[c * width * height + p] = data[p * channels + c];
        }
    }
    Tensor::from_data(TensorData::new(out, [3, height, width]), device)
}
