//! The real binary, run as a user would: outputs, and clear errors with exit code 2 on bad input. One
//! module per command (or concern), the shared helpers in `common`.

mod bad_input;
mod baseline;
mod common;
mod data;
mod demo;
mod help;
mod psv;
mod render;
mod train;
