//! The whole-MPI state between nets, in f32 or IEEE half floats.

use super::tiling::Rect;
use burn::tensor::{Device, Tensor, TensorData};
use half::f16;
use half::slice::HalfFloatSliceExt;

/// How the whole-MPI state is stored between nets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StatePrecision {
    F32,
    /// IEEE half floats (see the `infer` module docs for the rounding).
    F16,
}

impl StatePrecision {
    /// `f32` or `f16`.
    pub fn name(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
        }
    }

    pub fn bytes(self) -> u64 {
        match self {
            Self::F32 => 4,
            Self::F16 => 2,
        }
    }
}

/// Storage of a `[D][C][H][W]` state between nets.
enum Values {
    F32(Vec<f32>),
    F16(Vec<f16>),
}

pub(super) struct StateStore {
    d: usize,
    c: usize,
    h: usize,
    w: usize,
    values: Values,
}

impl StateStore {
    pub(super) fn new(d: usize, c: usize, h: usize, w: usize, precision: StatePrecision) -> Self {
        let n = d * c * h * w;
        let values = match precision {
            StatePrecision::F32 => Values::F32(vec![0.0; n]),
            StatePrecision::F16 => Values::F16(vec![f16::ZERO; n]),
        };
        Self { d, c, h, w, values }
    }

    /// Channels `c0..c0 + nc` of window `r`, as f32 `[D][nc][r.h][r.w]`.
    pub(super) fn read(&self, c0: usize, nc: usize, r: Rect) -> Vec<f32> {
        let (x, y, rw, rh) = r;
        let mut out = vec![0f32; self.d * nc * rw * rh];
        for p in 0..self.d {
            for c in 0..nc {
                for row in 0..rh {
                    let src = ((p * self.c + c0 + c) * self.h + y + row) * self.w + x;
                    let dst = ((p * nc + c) * rh + row) * rw;
                    let out = &mut out[dst..dst + rw];
                    match &self.values {
                        Values::F32(v) => out.copy_from_slice(&v[src..src + rw]),
                        Values::F16(v) => v[src..src + rw].convert_to_f32_slice(out),
                    }
                }
            }
        }
        out
    }

    /// Write `vals` `[np][C][r.h][r.w]` (all channels of planes `p0..p0 + np`) into window `r`.
    pub(super) fn write(&mut self, vals: &[f32], p0: usize, np: usize, r: Rect) {
        let (x, y, rw, rh) = r;
        let mut row_buf = vec![0f32; rw];
        for p in 0..np {
            for c in 0..self.c {
                for row in 0..rh {
                    let src = &vals[((p * self.c + c) * rh + row) * rw..][..rw];
                    let dst = (((p0 + p) * self.c + c) * self.h + y + row) * self.w + x;
                    match &mut self.values {
                        Values::F32(v) => v[dst..dst + rw].copy_from_slice(src),
                        Values::F16(v) => {
                            for (b, &s) in row_buf.iter_mut().zip(src) {
                                *b = s.clamp(-65504.0, 65504.0);
                            }
                            v[dst..dst + rw].convert_from_f32_slice(&row_buf);
                        }
                    }
                }
            }
        }
    }

    pub(super) fn tensor(&self, c0: usize, nc: usize, r: Rect, device: &Device) -> Tensor<4> {
        Tensor::from_data(
            TensorData::new(self.read(c0, nc, r), [self.d, nc, r.3, r.2]),
            device,
        )
    }
}
