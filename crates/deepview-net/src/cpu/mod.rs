//! The CPU engine: the network's operations on plain `f32` arrays with [`deepview_kernels`], one job per
//! module (within the engine each module imports only modules listed before it):
//! - `planes`: one thread's scratch planes, work dealt to one task per thread, the maximum of planes;
//! - [`fused`]: a whole core net as one differentiable operation (its forward and backward);
//! - [`renderops`]: the warp and over-compositing of the forward model (forward and backward);
//! - [`ops`]: the burn extension ops (a 3x3 conv, the fused core net, the warp, the composite) with
//!   their backward passes, for the `flex` CPU backend and autodiff on top of it;
//! - [`packed`]: a core net packed into plain arrays for inference, one plane per thread;
//! - `prior`, `warps`: the engine's agreement prior and its warps into the nets' padded planes;
//! - `renders`: the views' renders an update net reads, streamed a block of planes at a time;
//! - `state`: the engine's state between nets, in f32 or half floats;
//! - [`engine`]: whole-image inference with the packed nets.

pub mod engine;
pub mod fused;
pub mod ops;
pub mod packed;
mod planes;
mod prior;
pub mod renderops;
mod renders;
mod state;
mod warps;
