//! Dataset readers and writers. Every format (LLFF, COLMAP, Spaces, light-field grids, nerfstudio
//! `transforms.json`) loads into one [`Scene`]: a list of views, each an image path and a
//! [`Camera`](deepview_geometry::Camera) in this project's conventions (OpenCV axes, camera-from-world
//! poses, pixel centres at +0.5), plus optional depth bounds.
//!
//! Foreign conventions are converted in exactly one place each (`deepview_geometry::convention`), and
//! every error names the file and the problem ([`DataError`]).
//!
//! Modules: `scene` (the types), `options` ([`LoadOptions`], [`SceneArgs`]), `load` (detection and
//! [`load_scene`]), `images` (a scene's image files), [`formats`] (one reader and writer per format),
//! `files` (file helpers), [`npy`] and [`pfm`] (array and depth-map files).

mod camera_json;
pub mod formats;
pub mod npy;
pub mod pfm;

mod error;
mod files;
mod images;
mod load;
mod options;
mod scene;

use std::path::{Path, PathBuf};

pub use error::DataError;
pub(crate) use files::{image_size, list_images, read_file, read_text, write_bytes, write_image};
pub use files::{unread_photos, view_file_name};
pub use load::{DETECTION_RULES, detect_format, load_scene};
pub use options::{LoadOptions, SceneArgs};
pub use scene::{Scene, SceneFormat, View};

pub use camera_json::read_camera_json;
pub use formats::colmap::{
    ColmapModel, read_colmap, write_colmap_text, write_colmap_text_observed,
};
pub use formats::lightfield::{
    LightFieldCameras, light_field_cameras, light_field_image_name, read_disparity_range,
    write_disparity_range, write_light_field,
};
pub use formats::llff::{read_poses_bounds, write_llff};
pub use formats::spaces::{spaces_relative_path, write_spaces_models};
pub use formats::transforms::{TRANSFORMS_JSON, write_transforms};

/// The data folder for tests and benchmarks: env `DEEPVIEW_DATA`, else `<workspace>/../shared/data` (the
/// repository-relative fallback is compiled in, so no command of the program looks here).
pub fn data_dir() -> PathBuf {
    match std::env::var_os("DEEPVIEW_DATA") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    }
}
