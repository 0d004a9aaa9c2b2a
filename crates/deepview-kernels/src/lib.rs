//! CPU kernels of the DeepView network: 3x3 "same" convolutions with fused bias and ELU (forward), and
//! their input and weight gradients, on zero-padded planar `f32` planes.
//!
//! Layout ([`Plane`]): one channel of one slice is a flat buffer holding the `h x w` image inside a
//! one-texel zero border (rows of `w + 2`), with a little slack before and after. A 3x3 tap is then a
//! constant offset in the flat index, so a kernel walks the whole plane as one vector loop (16 outputs
//! per step in two AVX2 registers, 32 in two AVX-512 ones) with no per-row edge cases; the border columns it computes are
//! discarded (zeroed) afterwards, so every buffer keeps zeros outside its interior and the output of one
//! layer is the padded input of the next. Channels are passed as lists of planes, so concatenating
//! channels (the network's `concat(features, max over views)`) costs nothing.
//!
//! The kernels run on one slice at a time on the calling thread; callers parallelise over slices. The
//! AVX-512 or AVX2 + FMA path is chosen at run time; a portable path gives the same results (to rounding)
//! elsewhere.

mod act;
pub mod conv;
mod elu;
pub mod fastmath;
mod scalar;
#[cfg(target_arch = "x86_64")]
mod x86;
#[cfg(target_arch = "x86_64")]
mod x86_512;

pub use act::Act;
pub use conv::{
    PackedConv, conv3x3, conv3x3_from, conv3x3_input_grad, conv3x3_weight_grad, elu_backward,
    relu_backward,
};

/// Floats before the padded image in a plane buffer (so the top-left tap of the first output is in
/// bounds).
pub const FRONT: usize = 16;
/// Slack for a kernel's overrun past the last interior row (at least one step of the widest kernel).
pub const BLOCK: usize = 48;

/// The geometry of one zero-padded plane of an `h x w` image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plane {
    pub h: usize,
    pub w: usize,
}

impl Plane {
    pub fn new(h: usize, w: usize) -> Self {
        Self { h, w }
    }
    /// Row pitch: the image row and its two border texels.
    pub fn pitch(self) -> usize {
        self.w + 2
    }
    /// First flat index a kernel computes (row 1, the left border column).
    pub fn start(self) -> usize {
        FRONT + self.pitch()
    }
    /// One past the last flat index of the interior rows.
    pub fn end(self) -> usize {
        FRONT + (self.h + 1) * self.pitch()
    }
    /// Length of a plane buffer: the padded image plus slack for a kernel's overrun (one step) and its
    /// taps (one row and one texel).
    pub fn len(self) -> usize {
        (FRONT + (self.h + 2) * self.pitch() + BLOCK + 16).next_multiple_of(16)
    }
    pub fn is_empty(self) -> bool {
        self.h == 0 || self.w == 0
    }
    /// Flat index of image texel `(x, y)`.
    pub fn index(self, y: usize, x: usize) -> usize {
        FRONT + (y + 1) * self.pitch() + x + 1
    }
    /// Tap offsets of a 3x3 kernel, row-major (`t = 3 * ky + kx`, offset `(ky - 1, kx - 1)`).
    pub fn taps(self) -> [isize; 9] {
        let p = self.pitch() as isize;
        let mut t = [0isize; 9];
        for ky in 0..3 {
            for kx in 0..3 {
                t[ky * 3 + kx] = (ky as isize - 1) * p + kx as isize - 1;
            }
        }
        t
    }
    /// A zeroed plane buffer.
    pub fn zeroed(self) -> Vec<f32> {
        vec![0.0; self.len()]
    }
    /// Copy an unpadded `h x w` image (row-major) into the interior of `dst`, whose border is zero.
    pub fn pad_into(self, src: &[f32], dst: &mut [f32]) {
        debug_assert_eq!(src.len(), self.h * self.w);
        for (y, row) in src.chunks_exact(self.w).enumerate() {
            let i = self.index(y, 0);
            dst[i..i + self.w].copy_from_slice(row);
        }
    }
    /// Copy the interior of `src` into an unpadded `h x w` image.
    pub fn unpad_into(self, src: &[f32], dst: &mut [f32]) {
        debug_assert_eq!(dst.len(), self.h * self.w);
        for (y, row) in dst.chunks_exact_mut(self.w).enumerate() {
            let i = self.index(y, 0);
            row.copy_from_slice(&src[i..i + self.w]);
        }
    }
    /// Zero what a kernel wrote outside the interior: the border columns and everything after the last
    /// interior row.
    pub fn clear_border(self, buf: &mut [f32]) {
        let p = self.pitch();
        for r in 1..=self.h {
            buf[FRONT + r * p] = 0.0;
            buf[FRONT + r * p + p - 1] = 0.0;
        }
        buf[self.end()..].fill(0.0);
    }
}

/// The instruction sets the kernels can run on, in increasing order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    Portable,
    /// AVX2 + FMA.
    Avx2,
    /// AVX-512F (with AVX2 + FMA).
    Avx512,
}

thread_local! {
    static CAP: std::cell::Cell<Isa> = const { std::cell::Cell::new(Isa::Avx512) };
}

/// Run `f` with the kernels of at most `cap` on this thread (tests compare every path; benchmarks
/// compare AVX2 against AVX-512 in one process).
pub fn with_isa_cap<R>(cap: Isa, f: impl FnOnce() -> R) -> R {
    let old = CAP.with(|p| p.replace(cap));
    let r = f();
    CAP.with(|p| p.set(old));
    r
}

/// The widest instruction set the whole process may use ([`set_process_isa`]; `deepview --isa`).
static PROCESS_CAP: std::sync::atomic::AtomicU8 =
    std::sync::atomic::AtomicU8::new(Isa::Avx512 as u8);

/// Cap the instruction set of the kernels for the whole process (`deepview --isa avx2|portable`: A/B
/// benchmarks, or a machine whose wide units misbehave).
pub fn set_process_isa(cap: Isa) {
    PROCESS_CAP.store(cap as u8, std::sync::atomic::Ordering::Relaxed);
}

fn process_cap() -> Isa {
    match PROCESS_CAP.load(std::sync::atomic::Ordering::Relaxed) {
        0 => Isa::Portable,
        1 => Isa::Avx2,
        _ => Isa::Avx512,
    }
}

/// Run `f` with the portable kernels on this thread ([`set_process_isa`] for a whole process).
pub fn with_portable<R>(f: impl FnOnce() -> R) -> R {
    with_isa_cap(Isa::Portable, f)
}

/// The best instruction set of this machine that the process allows ([`set_process_isa`]).
pub fn detected() -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        use std::sync::OnceLock;
        static HAS: OnceLock<Isa> = OnceLock::new();
        let hardware = *HAS.get_or_init(|| {
            if !(is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) {
                Isa::Portable
            } else if is_x86_feature_detected!("avx512f") {
                Isa::Avx512
            } else {
                Isa::Avx2
            }
        });
        hardware.min(process_cap())
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Isa::Portable
    }
}

/// The instruction set the kernels run on (on this machine and thread).
pub fn isa() -> Isa {
    detected().min(CAP.with(|p| p.get()))
}

/// Whether the AVX2 (or wider) kernels run (on this machine and thread).
pub fn simd() -> bool {
    isa() >= Isa::Avx2
}

/// Give the heap's free memory back to the kernel (glibc's `malloc_trim`; nothing elsewhere): after a
/// phase whose large buffers are freed, so that the next phase's buffers do not come on top of them (the
/// application raises glibc's trim threshold, so freed blocks otherwise stay resident).
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the heap to the kernel.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// A zeroed buffer of `n` floats; a large one (64 MiB and more) is backed by transparent huge pages
/// where the kernel offers them on request (`madvise`; Linux's default `enabled = madvise`): the
/// engine's state, renders and prior (hundreds of MB) then fault in 2 MiB at a time instead of 4 KiB
/// (measured: 6.5% less CPU for `bench net --preset cpu`, most of it the kernel's page-fault path).
pub fn zeroed_buffer(n: usize) -> Vec<f32> {
    #[cfg(target_os = "linux")]
    if n * 4 >= 64 << 20 {
        const HUGE: usize = 2 << 20;
        let mut v: Vec<f32> = Vec::with_capacity(n);
        let p = v.as_mut_ptr() as usize;
        let (a, e) = (p.next_multiple_of(HUGE), (p + n * 4) & !(HUGE - 1));
        if e > a {
            // SAFETY: advice on pages of this allocation, which nothing has touched yet; a failure
            // (no THP) leaves ordinary pages.
            unsafe { libc::madvise(a as *mut libc::c_void, e - a, libc::MADV_HUGEPAGE) };
        }
        v.resize(n, 0.0);
        return v;
    }
    vec![0.0; n]
}
