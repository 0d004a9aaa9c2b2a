//! The views' renders that an update net reads (`I`, `R`, and per plane `A`, `T`; see
//! [`crate::forward`]), streamed a block of planes at a time instead of held for every plane at once.
//!
//! Per view pixel, `A_p` is the over-composite of the planes behind `p` (`0..p`, back to front) and
//! `T_p` the transmittance of the planes in front of it (`p + 1..D`); `R` is the composite of all
//! planes. The engine updates the state in place, block after block from the front, so a block's
//! renders must come from the state before any update:
//! - [`ViewRenders::new`] renders every plane once, back to front, into each view's `R` and keeps the
//!   running composite at the start of every block (`K` three-channel view images per block);
//! - [`ViewRenders::render_block`] then renders one block's planes (not yet updated), starting from its
//!   kept composite and from the running transmittance of the blocks in front (updated before it, but
//!   rendered before their update and carried here).
//!
//! Per pixel the arithmetic and its order are those of one pass over all planes (the composite's
//! definition), whatever the block size: the results are the same to the bit. Memory: per view `I` and
//! `R`, the transmittance, the kept composites and one block's `A`/`T`, instead of `A`/`T` of every
//! plane (4 values per plane and view pixel).

use crate::forward::{Hom, invert};
use deepview_image::ImageF32;
use deepview_kernels::fastmath;
use deepview_mpi::warp::{RowTaps, Sampler};
use rayon::prelude::*;
use std::ops::Range;

/// The planes `0..d` in blocks of `block` planes.
pub(crate) fn blocks(d: usize, block: usize) -> Vec<Range<usize>> {
    let block = block.max(1);
    (0..d.div_ceil(block))
        .map(|i| i * block..((i + 1) * block).min(d))
        .collect()
}

/// The block size (a multiple of `threads`, so that every thread gets as many of a block's planes) that
/// minimises [`stream_bytes`] for `d` planes.
pub(crate) fn block_size(d: usize, threads: usize, view_px: u64, plane_px: u64) -> usize {
    let threads = threads.max(1);
    (1..=d.div_ceil(threads).max(1))
        .map(|m| m * threads)
        .min_by_key(|&b| stream_bytes(d, b, view_px, plane_px))
        .unwrap_or(threads)
}

/// Bytes of [`ViewRenders`] and of one block's RGBA for `d` planes in blocks of `block`: `view_px` is
/// the views' pixel count (all views), `plane_px` an MPI plane's.
pub(crate) fn stream_bytes(d: usize, block: usize, view_px: u64, plane_px: u64) -> u64 {
    let nb = d.div_ceil(block.max(1)) as u64;
    let b = block.min(d) as u64;
    // I and R (6), the transmittance (1), a kept composite per block after the first (3), one block's
    // A/T (4 per plane) and its planes' RGBA (4 per MPI texel).
    4 * (view_px * (6 + 1 + 3 * nb.saturating_sub(1) + 4 * b) + plane_px * 4 * b)
}

/// One view's per-row samplers of every plane (MPI texels into view pixels).
struct View<'a> {
    img: &'a ImageF32,
    samplers: Vec<Sampler>,
}

/// The streamed renders of one state into every view (see the module docs).
pub(crate) struct ViewRenders<'a> {
    views: Vec<View<'a>>,
    blocks: Vec<Range<usize>>,
    /// Per view `[y][x][6]`: `I` (the view's image) and `R` (the composite of every plane).
    pub(crate) ir: Vec<Vec<f32>>,
    /// Per view and block after the first, the composite of the planes behind the block (`[y][x][3]`).
    behind: Vec<Vec<Vec<f32>>>,
    /// Per view, the transmittance of the planes in front of the next block to render (`[y][x]`).
    front: Vec<Vec<f32>>,
    /// Per view, the last rendered block's `[plane][y][x][4]`: `A` (3) and `T` (1).
    at: Vec<Vec<f32>>,
}

impl<'a> ViewRenders<'a> {
    /// Render every plane of the MPI into every view (`R` and the kept composites). `rgba(block, out)`
    /// writes the premultiplied RGBA (`[plane][H][W][4]`) of a block's planes of the current state;
    /// `homs[v][p]` maps MPI plane `p` into view `v`; the MPI is `w x h`.
    pub(crate) fn new(
        views: &'a [(ImageF32, deepview_geometry::Camera)],
        homs: &[Vec<Hom>],
        (w, h): (usize, usize),
        blocks: Vec<Range<usize>>,
        rgba: &mut dyn FnMut(Range<usize>, &mut Vec<f32>),
        buf: &mut Vec<f32>,
    ) -> Self {
        let views: Vec<View> = views
            .iter()
            .zip(homs)
            .map(|((img, _), homs)| View {
                img,
                samplers: homs
                    .iter()
                    .map(|m| Sampler::new(invert(m), w as u32, h as u32))
                    .collect(),
            })
            .collect();
        let px = |v: &View| v.img.width as usize * v.img.height as usize;
        // The running composite, `[y][x][3]` per view.
        let mut acc: Vec<Vec<f32>> = views.iter().map(|v| vec![0f32; px(v) * 3]).collect();
        let mut behind: Vec<Vec<Vec<f32>>> = views.iter().map(|_| Vec::new()).collect();
        for (i, blk) in blocks.iter().enumerate() {
            if i > 0 {
                for (b, a) in behind.iter_mut().zip(&acc) {
                    b.push(a.clone());
                }
            }
            rgba(blk.clone(), buf);
            for (view, acc) in views.iter().zip(&mut acc) {
                let vw = view.img.width as usize;
                acc.par_chunks_mut(vw * 3).enumerate().for_each_init(
                    RowTaps::default,
                    |taps, (y, acc)| {
                        composite_rows(buf, (w, h), view, blk.clone(), y, acc, None, taps)
                    },
                );
            }
        }
        let ir = views
            .iter()
            .zip(&acc)
            .map(|(view, acc)| {
                let img = view.img;
                let mut ir = vec![0f32; px(view) * 6];
                for (i, (o, r)) in ir.chunks_exact_mut(6).zip(acc.chunks_exact(3)).enumerate() {
                    o[..3].copy_from_slice(&img.data[i * img.channels..][..3]);
                    o[3..].copy_from_slice(r);
                }
                ir
            })
            .collect();
        let front = views.iter().map(|v| vec![1f32; px(v)]).collect();
        Self {
            views,
            blocks,
            ir,
            behind,
            front,
            at: Vec::new(),
        }
    }

    /// Render block `i`'s planes (`rgba`, as from the `rgba` of [`Self::new`], of the state before any
    /// update) into every view's `A`/`T` ([`Self::at_plane`]). Blocks go from the front (the last) to
    /// the back (the first), each once.
    pub(crate) fn render_block(&mut self, i: usize, rgba: &[f32], (w, h): (usize, usize)) {
        let blk = self.blocks[i].clone();
        let n = blk.len();
        self.at.resize_with(self.views.len(), Vec::new);
        for (v, view) in self.views.iter().enumerate() {
            let vw = view.img.width as usize;
            let vpx = vw * view.img.height as usize;
            let at = &mut self.at[v];
            at.resize(n * vpx * 4, 0.0);
            let ptr = at.as_mut_ptr() as usize;
            let behind = (i > 0).then(|| &self.behind[v][i - 1]);
            self.front[v].par_chunks_mut(vw).enumerate().for_each_init(
                RowTaps::default,
                |taps, (y, t)| {
                    let mut acc = match behind {
                        Some(b) => b[y * vw * 3..(y + 1) * vw * 3].to_vec(),
                        None => vec![0f32; vw * 3],
                    };
                    let out = AtRows {
                        ptr,
                        plane_stride: vpx * 4,
                        row_offset: y * vw * 4,
                    };
                    composite_rows(
                        rgba,
                        (w, h),
                        view,
                        blk.clone(),
                        y,
                        &mut acc,
                        Some(out),
                        taps,
                    );
                    // Front to back: `T_p` is the product of `1 - alpha` of the planes in front.
                    for p in blk.clone().rev() {
                        // SAFETY: row `y` of the block's plane `p`, written by this task only.
                        let row = unsafe { out.row(p - blk.start, vw) };
                        for (x, t) in t.iter_mut().enumerate() {
                            let alpha = row[x * 4 + 3];
                            row[x * 4 + 3] = *t;
                            if p > 0 {
                                *t *= 1.0 - alpha;
                            }
                        }
                    }
                },
            );
        }
    }

    /// Plane `p`'s `A`/`T` in view `v` (`[y][x][4]`) from the last [`Self::render_block`], whose block
    /// holds `p`.
    pub(crate) fn at_plane(&self, v: usize, block: usize, p: usize) -> &[f32] {
        let img = self.views[v].img;
        let vpx = img.width as usize * img.height as usize;
        &self.at[v][(p - self.blocks[block].start) * vpx * 4..][..vpx * 4]
    }
}

/// Where a composite row writes `A` and the planes' alpha: the block's plane `j`'s row at `ptr +
/// j * plane_stride + row_offset` (floats).
#[derive(Clone, Copy)]
struct AtRows {
    ptr: usize,
    plane_stride: usize,
    row_offset: usize,
}

impl AtRows {
    /// # Safety
    /// The row must lie in the buffer behind `ptr` and be accessed by this task only.
    unsafe fn row<'b>(&self, j: usize, vw: usize) -> &'b mut [f32] {
        unsafe {
            std::slice::from_raw_parts_mut(
                (self.ptr as *mut f32).add(j * self.plane_stride + self.row_offset),
                vw * 4,
            )
        }
    }
}

/// Row `y` of one view, planes `blk` back to front over `acc` (`[x][3]`): with `out`, each plane's row
/// of `[A (3), alpha]` first (`A` the composite before the plane). `rgba` holds the block's planes.
#[allow(clippy::too_many_arguments)]
fn composite_rows(
    rgba: &[f32],
    (w, h): (usize, usize),
    view: &View,
    blk: Range<usize>,
    y: usize,
    acc: &mut [f32],
    out: Option<AtRows>,
    taps: &mut RowTaps,
) {
    fastmath::with_simd(
        #[inline(always)]
        || {
            let vw = view.img.width as usize;
            for p in blk.clone() {
                view.samplers[p].row(y as u32).taps_into(vw, taps);
                let plane = &rgba[(p - blk.start) * h * w * 4..][..h * w * 4];
                // SAFETY: row `y` of the block's plane `p`, written by this task only.
                let mut row = out.map(|o| unsafe { o.row(p - blk.start, vw) });
                for x in 0..vw {
                    let (c, a) = match taps.tap(x) {
                        None => ([0f32; 3], 0f32),
                        Some(t) => {
                            let mut s = [0f32; 4];
                            for j in 0..4 {
                                let q = &plane[t.idx[j] as usize * 4..][..4];
                                for c in 0..4 {
                                    s[c] += t.w[j] * q[c];
                                }
                            }
                            ([s[0], s[1], s[2]], s[3])
                        }
                    };
                    let ax = &mut acc[x * 3..x * 3 + 3];
                    if let Some(row) = row.as_deref_mut() {
                        row[x * 4..x * 4 + 4].copy_from_slice(&[ax[0], ax[1], ax[2], a]);
                    }
                    let om = 1.0 - a;
                    for ch in 0..3 {
                        ax[ch] = ax[ch] * om + c[ch];
                    }
                }
            }
        },
    )
}
