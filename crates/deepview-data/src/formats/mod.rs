//! One module per dataset format, each with its reader (`load`) and the writer used by the synthetic-scene
//! generator.

pub mod colmap;
pub mod lightfield;
pub mod llff;
pub mod spaces;
pub mod transforms;
