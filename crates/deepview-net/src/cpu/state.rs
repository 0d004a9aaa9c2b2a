//! The engine's state between nets (`[D][S][H*W]`), in f32 or, where that does not fit the budget, in
//! IEEE half floats ([`StatePrecision::F16`]: the nets compute in f32 on one plane at a time, widened
//! into a per-thread buffer and rounded back to 11 significant bits after its update).

use crate::infer::StatePrecision;
use half::f16;
use half::slice::HalfFloatSliceExt;

enum Values {
    F32(Vec<f32>),
    F16(Vec<f16>),
}

/// The state of `d` planes of `s` channels of `hw` pixels. Planes are read and written through
/// [`Self::with_plane`] / [`Self::with_plane_ref`], by one task per plane at a time.
pub(crate) struct EngineState {
    values: Values,
    /// Floats per plane (`s * hw`).
    len: usize,
    ptr: usize,
}

impl EngineState {
    pub(crate) fn new(d: usize, s: usize, hw: usize, precision: StatePrecision) -> Self {
        let mut values = match precision {
            StatePrecision::F32 => Values::F32(deepview_kernels::zeroed_buffer(d * s * hw)),
            StatePrecision::F16 => Values::F16(vec![f16::ZERO; d * s * hw]),
        };
        let ptr = match &mut values {
            Values::F32(v) => v.as_mut_ptr() as usize,
            Values::F16(v) => v.as_mut_ptr() as usize,
        };
        Self {
            values,
            len: s * hw,
            ptr,
        }
    }

    /// Plane `p` (`[S][H*W]`) as f32 to `f`, which may change it (`buf`: the widened copy of a half-float
    /// state).
    ///
    /// # Safety
    /// No other task accesses plane `p` meanwhile.
    pub(crate) unsafe fn with_plane<R>(
        &self,
        p: usize,
        buf: &mut Vec<f32>,
        f: impl FnOnce(&mut [f32]) -> R,
    ) -> R {
        match &self.values {
            Values::F32(_) => {
                // SAFETY: plane p of the buffer, accessed by this task only (the caller's contract).
                let st = unsafe {
                    std::slice::from_raw_parts_mut(
                        (self.ptr as *mut f32).add(p * self.len),
                        self.len,
                    )
                };
                f(st)
            }
            Values::F16(_) => {
                // SAFETY: as above.
                let st = unsafe {
                    std::slice::from_raw_parts_mut(
                        (self.ptr as *mut f16).add(p * self.len),
                        self.len,
                    )
                };
                buf.resize(self.len, 0.0);
                st.convert_to_f32_slice(buf);
                let r = f(buf);
                st.convert_from_f32_slice(buf);
                r
            }
        }
    }

    /// Plane `p` as f32 to `f`, read only.
    ///
    /// # Safety
    /// No task writes plane `p` meanwhile.
    pub(crate) unsafe fn with_plane_ref<R>(
        &self,
        p: usize,
        buf: &mut Vec<f32>,
        f: impl FnOnce(&[f32]) -> R,
    ) -> R {
        match &self.values {
            // SAFETY: plane p of the buffer, written by no task meanwhile (the caller's contract).
            Values::F32(_) => f(unsafe {
                std::slice::from_raw_parts((self.ptr as *const f32).add(p * self.len), self.len)
            }),
            Values::F16(_) => {
                // SAFETY: as above.
                let st = unsafe {
                    std::slice::from_raw_parts((self.ptr as *const f16).add(p * self.len), self.len)
                };
                buf.resize(self.len, 0.0);
                st.convert_to_f32_slice(buf);
                f(buf)
            }
        }
    }

    /// The premultiplied RGBA `[D][H*W][4]` of an f32 state of four channels, made in the state's own
    /// buffer (the same size: no second buffer of the whole MPI), a plane per task through a copy of
    /// its logits.
    pub(crate) fn into_rgba(self, hw: usize) -> Vec<f32> {
        use rayon::prelude::*;
        assert_eq!(self.len, 4 * hw, "an RGBA-sized state");
        let Values::F32(mut values) = self.values else {
            panic!("an f32 state");
        };
        if hw > 0 {
            values.par_chunks_mut(4 * hw).for_each_init(
                Vec::new,
                |logits: &mut Vec<f32>, plane| {
                    logits.clear();
                    logits.extend_from_slice(plane);
                    crate::cpu::engine::plane_to_rgba(logits, hw, plane);
                },
            );
        }
        values
    }
}

// SAFETY: the raw pointer is the buffer's own; planes are accessed by one task at a time (the methods'
// contracts).
unsafe impl Sync for EngineState {}
