//! nerfstudio / instant-ngp `transforms.json`: camera-to-world `transform_matrix` per frame in OpenGL axes
//! (columns [right, up, back, centre], converted by `opengl_c2w_to_pose`), and pinhole intrinsics shared at
//! the top level or given per frame (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`; instant-ngp's `camera_angle_x`
//! / `camera_angle_y` instead of focal lengths).
//!
//! - `camera_model`: PINHOLE, SIMPLE_PINHOLE, or OPENCV (the default) whose distortion `k1..k4`, `p1`, `p2`
//!   must be zero: distorted cameras are refused with a message saying how to undistort them.
//! - `file_path` is relative to the JSON's folder, with or without an extension (png, jpg, jpeg tried).
//! - Downscaled copies (`images_2/`, `images_4/`, nerfstudio's `downscale_factor` folders): `--images
//!   images_4` replaces the first folder of every `file_path`; intrinsics are scaled to the size of the
//!   images actually found (an image whose size is not the JSON's `w x h` scaled is an error).
//! - Depth bounds: top-level `near` and `far` when present, else the `aabb` ([[min], [max]]) when all its
//!   corners lie in front of every camera, else none (`--near/--far` are then required).
//!
//! Principal points follow the same convention as COLMAP and this project (the centre of the top-left pixel
//! is at (0.5, 0.5)), so they are used as given.
//!
//! `file` holds the file's mirror types and the cameras' resolution, `load` the scene loader, `write`
//! the writer.

mod file;
mod load;
mod write;

pub use file::{
    FrameIntrinsics, TRANSFORMS_JSON, TransformsCamera, TransformsFile, TransformsFrame,
    TransformsIntrinsics, parse_transforms, transforms_cameras,
};
pub(crate) use load::load;
pub use load::{transforms_depth_bounds, transforms_path};
pub use write::{transforms_file, write_transforms};

#[cfg(test)]
mod tests;
