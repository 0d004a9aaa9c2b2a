//! What every convolution kernel (scalar, AVX2, AVX-512) shares: the fused activation and the output
//! block width.

/// The activation fused into a convolution's output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Act {
    Linear,
    /// `x` for `x > 0`, `exp(x) - 1` otherwise (ELU with alpha 1).
    Elu,
    /// `max(x, 0)`.
    Relu,
}

/// Output channels per kernel pass.
pub const CO_BLOCK: usize = 8;
