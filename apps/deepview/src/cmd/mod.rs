//! One module per subcommand: `Args` (clap) and `run`.

pub mod bench;
pub mod depth;
pub mod info;
pub mod psv;
pub mod render;
pub mod synth;
