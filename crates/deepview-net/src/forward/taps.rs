//! The bilinear taps of homography warps ([`WarpTable`], made once per warp on the CPU; homographies are
//! [`Hom`]): the data that both the burn warp ([`WarpTable::apply`]) and the CPU operations
//! ([`crate::cpu::renderops`]) read.

use std::sync::{Arc, OnceLock};

/// A row-major 3x3 homography (f64), output pixels -> source pixels.
pub type Hom = [f64; 9];

/// Precomputed bilinear taps of `planes` homography warps from a `src_w x src_h` source to an
/// `out_w x out_h` output.
#[derive(Clone, Debug)]
pub struct WarpTable {
    pub planes: usize,
    pub src_w: usize,
    pub src_h: usize,
    pub out_w: usize,
    pub out_h: usize,
    /// The homographies (output pixels -> source pixels, one per plane) and the frames: what the taps
    /// are computed from, on the CPU ([`Self::taps`]) or on a GPU ([`Self::coefficients`]).
    homs: Arc<[Hom]>,
    frames: Frames,
    /// The taps, computed on first use (a GPU warp computes its own and never asks) and shared, so that
    /// a clone is cheap: [`Self::apply`] hands one to the CPU operation, which keeps it for the backward.
    computed: Arc<OnceLock<Taps>>,
}

#[derive(Debug)]
struct Taps {
    /// `[4][planes * out_h * out_w]` texel indices within one source plane (`y * src_w + x`).
    idx: Vec<i64>,
    /// `[4][planes * out_h * out_w]` bilinear weights (0 for invalid samples).
    w: Vec<f32>,
    /// `[planes * out_h * out_w]`: 1 where the sample is inside the source.
    valid: Vec<f32>,
}

/// A [`WarpTable`]'s taps by source texel ([`WarpTable::transposed`]): the warp's adjoint as a
/// gather, in i32 (the order of sums the GPU backward follows; tests check it against the scatter).
#[derive(Clone, Debug, PartialEq)]
pub struct TransposedTaps {
    pub offsets: Vec<i32>,
    pub pos: Vec<i32>,
    pub w: Vec<f32>,
}

/// Where a warp's source and output arrays lie in the frames its homographies map between: a crop of
/// a larger image (or MPI) as source, a window of a larger output. Sample positions, validity (inside
/// the *whole* source) and edge clamping are computed in the whole frames exactly as for the uncropped
/// warp, and only the texel indices move by the source crop's integer origin, so a cropped warp is bit
/// for bit the matching part of the whole one (shifting the homographies instead would round
/// differently, and a sample within f32 rounding of the source's edge could flip between valid and not).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frames {
    /// Origin of the source array in the source frame.
    pub src_origin: (usize, usize),
    /// Size of the whole source (validity and edge clamping).
    pub src_full: (usize, usize),
    /// Origin of the output array in the output frame.
    pub out_origin: (usize, usize),
}

impl Frames {
    /// Uncropped: the source array is the whole `src_w x src_h` source, the output starts at 0.
    pub fn whole(src_w: usize, src_h: usize) -> Self {
        Self {
            src_origin: (0, 0),
            src_full: (src_w, src_h),
            out_origin: (0, 0),
        }
    }
}

impl WarpTable {
    /// Taps of `homs.len()` warps (one per plane). Empty sources or outputs are allowed (all invalid).
    pub fn new(homs: &[Hom], src_w: usize, src_h: usize, out_w: usize, out_h: usize) -> Self {
        Self::new_framed(
            homs,
            Frames::whole(src_w, src_h),
            src_w,
            src_h,
            out_w,
            out_h,
        )
    }

    /// Taps of warps whose `src_w x src_h` source and `out_w x out_h` output are crops ([`Frames`]) of
    /// the frames `homs` map between. The source crop must hold every texel a valid sample reads
    /// (texel indices are clamped to it).
    pub fn new_framed(
        homs: &[Hom],
        frames: Frames,
        src_w: usize,
        src_h: usize,
        out_w: usize,
        out_h: usize,
    ) -> Self {
        Self {
            planes: homs.len(),
            src_w,
            src_h,
            out_w,
            out_h,
            homs: homs.into(),
            frames,
            computed: Arc::new(OnceLock::new()),
        }
    }

    /// The taps, computed on the first call.
    fn computed(&self) -> &Taps {
        self.computed.get_or_init(|| {
            let (homs, frames) = (&self.homs[..], self.frames);
            let (sw, sh, ow, oh) = (self.src_w, self.src_h, self.out_w, self.out_h);
            #[cfg(target_arch = "x86_64")]
            if deepview_kernels::simd() {
                // SAFETY: the CPU has AVX2 and FMA (checked): the same code with hardware
                // `fma`/`floor` instead of libm calls (identical results: `mul_add` is exact either way).
                return unsafe { Self::compute_fma(homs, frames, sw, sh, ow, oh) };
            }
            Self::compute_portable(homs, frames, sw, sh, ow, oh)
        })
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn compute_fma(
        homs: &[Hom],
        frames: Frames,
        src_w: usize,
        src_h: usize,
        out_w: usize,
        out_h: usize,
    ) -> Taps {
        Self::compute_portable(homs, frames, src_w, src_h, out_w, out_h)
    }

    /// Per plane `a = [h0, h3, h6]` and per output row `y` `b = [h1 v + h2, h4 v + h5, h7 v + h8]`
    /// (`v` the row's centre in the output frame, in f64), all rounded to f32: the projective sample
    /// position of output column centre `u` is `(a0 u + b0, a1 u + b1) / (a2 u + b2)`. The taps
    /// ([`Self::taps`]) are computed from these numbers, and a GPU warp computes its own from them
    /// (layout `[planes][3 + 3 * out_h]`).
    pub fn coefficients(&self) -> Vec<f32> {
        let uy = self.frames.out_origin.1;
        let mut out = Vec::with_capacity(self.planes * (3 + 3 * self.out_h));
        for h in self.homs.iter() {
            out.extend([h[0] as f32, h[3] as f32, h[6] as f32]);
            for y in 0..self.out_h {
                out.extend(row_coefficients(h, (uy + y) as f64 + 0.5));
            }
        }
        out
    }

    /// The inverse homographies (source pixels -> output pixels, both in their whole frames), `[planes][9]`
    /// row-major in f32: where a GPU warp's backward looks for the samples that read a source texel.
    pub fn inverse_coefficients(&self) -> Vec<f32> {
        self.homs
            .iter()
            .flat_map(|h| super::warp::invert(h).map(|v| v as f32))
            .collect()
    }

    /// The frames the homographies map between.
    pub fn frames(&self) -> Frames {
        self.frames
    }

    #[inline(always)]
    fn compute_portable(
        homs: &[Hom],
        frames: Frames,
        src_w: usize,
        src_h: usize,
        out_w: usize,
        out_h: usize,
    ) -> Taps {
        let n = homs.len() * out_w * out_h;
        let mut idx = vec![0i64; 4 * n];
        let mut w = vec![0f32; 4 * n];
        let mut valid = vec![0f32; n];
        let (full_w, full_h) = frames.src_full;
        let (wf, hf) = (full_w as f32, full_h as f32);
        let (wmax, hmax) = (full_w as i32 - 1, full_h as i32 - 1);
        let (ox, oy) = (frames.src_origin.0 as i32, frames.src_origin.1 as i32);
        let (cwmax, chmax) = (src_w as i32 - 1, src_h as i32 - 1);
        let (ux, uy) = frames.out_origin;
        for (d, h) in homs.iter().enumerate() {
            let a = [h[0] as f32, h[3] as f32, h[6] as f32];
            for y in 0..out_h {
                let b = row_coefficients(h, (uy + y) as f64 + 0.5);
                for x in 0..out_w {
                    let o = (d * out_h + y) * out_w + x;
                    let u = (ux + x) as f32 + 0.5;
                    let wn = a[2].mul_add(u, b[2]);
                    if wn <= 0.0 || src_w == 0 || src_h == 0 || full_w == 0 || full_h == 0 {
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
                    // Clamped to the whole source, then moved into the crop.
                    let cx = |x: i32| (x.clamp(0, wmax) - ox).clamp(0, cwmax) as i64;
                    let cy = |y: i32| (y.clamp(0, hmax) - oy).clamp(0, chmax) as i64 * src_w as i64;
                    let (xa, xb, ya, yb) = (cx(x0), cx(x0 + 1), cy(y0), cy(y0 + 1));
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
        Taps { idx, w, valid }
    }

    /// The bilinear taps: `[4][planes * out_h * out_w]` source texel indices within one plane and
    /// weights (0 for invalid samples). Computed on the first call.
    pub fn taps(&self) -> (&[i64], &[f32]) {
        let t = self.computed();
        (&t.idx, &t.w)
    }

    /// The taps transposed (the warp's adjoint, for a gather-only backward): for each source texel of
    /// `s` source planes (`s` the table's planes, or 1 for a broadcast source), the output samples that
    /// read it. Entries `offsets[e]..offsets[e + 1]` belong to source element `e` (plane-major,
    /// `[s][src_h][src_w]`); `pos` is the sample (`[planes][out_h][out_w]`) and `w` its tap's weight.
    /// Taps of weight 0 are left out; each element's entries are in sample order.
    pub fn transposed(&self, s: usize) -> TransposedTaps {
        assert!(s == self.planes || s == 1, "warp source has {s} planes");
        let per = self.out_h * self.out_w;
        let shw = self.src_h * self.src_w;
        let taps = self.computed();
        let n = taps.valid.len();
        let key = |t: usize, k: usize| {
            let texel = taps.idx[t * n + k] as usize;
            if s == 1 {
                texel
            } else {
                (k / per) * shw + texel
            }
        };
        let mut offsets = vec![0usize; s * shw + 1];
        for k in 0..n {
            for t in 0..4 {
                if taps.w[t * n + k] != 0.0 {
                    offsets[key(t, k) + 1] += 1;
                }
            }
        }
        for e in 0..s * shw {
            offsets[e + 1] += offsets[e];
        }
        let total = offsets[s * shw];
        assert!(
            total <= i32::MAX as usize && n <= i32::MAX as usize,
            "warp too large for i32 taps"
        );
        let mut next = offsets.clone();
        let mut pos = vec![0i32; total];
        let mut w = vec![0f32; total];
        for k in 0..n {
            for t in 0..4 {
                let v = taps.w[t * n + k];
                if v != 0.0 {
                    let e = key(t, k);
                    pos[next[e]] = k as i32;
                    w[next[e]] = v;
                    next[e] += 1;
                }
            }
        }
        TransposedTaps {
            offsets: offsets.into_iter().map(|o| o as i32).collect(),
            pos,
            w,
        }
    }

    /// The validity mask as plain data, `[planes][out_h][out_w]`.
    pub fn valid_data(&self) -> &[f32] {
        &self.computed().valid
    }
}

/// The row coefficients `b` of [`WarpTable::coefficients`] for output row centre `v`.
fn row_coefficients(h: &Hom, v: f64) -> [f32; 3] {
    [
        (h[1] * v + h[2]) as f32,
        (h[4] * v + h[5]) as f32,
        (h[7] * v + h[8]) as f32,
    ]
}
