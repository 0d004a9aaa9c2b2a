//! The real binary, run as a user would: outputs, and clear errors with exit code 2 on bad input. One
//! module per command (or concern), the helpers shared with the other test crates in `../common`.

mod bad_input;
mod baseline;
#[path = "../common/mod.rs"]
mod common;
mod data;
mod demo;
mod help;
mod psv;
mod render;
mod streams;
mod train;
