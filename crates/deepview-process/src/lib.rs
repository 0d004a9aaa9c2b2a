//! From a folder of photos (or a video) to a posed scene, like nerfstudio's `ns-process-data`: runs COLMAP
//! (CPU SIFT, no display) through feature extraction, matching, mapping and undistortion, and writes a
//! COLMAP scene folder that every `deepview` command reads:
//!
//! ```text
//! SCENE_DIR/images/        undistorted photos (one shared PINHOLE camera)
//! SCENE_DIR/sparse/0/      cameras.bin, images.bin, points3D.bin (depth bounds come from the points)
//! SCENE_DIR/colmap.log     COLMAP's (and ffmpeg's) own output, stage by stage
//! SCENE_DIR/colmap/        database.db and the model before undistortion
//! ```
//!
//! Existing output is never replaced: the scene is built in the sibling folder `SCENE_DIR.incomplete` and
//! renamed into place at the end. After a failure that folder is removed and COLMAP's log is kept beside
//! the output as `SCENE_DIR.colmap.log` (named in the error) for inspection.
//!
//! Modules: `options` (what to do, what is reported), `pipeline` ([`process`]), `photos` (listing and
//! copying the input), `frames` (video input through ffmpeg), `colmap` (COLMAP's command lines and its
//! models), `runner` (running programs into the log), `layout` (the output and working folders), `error`.

mod colmap;
mod error;
mod frames;
mod layout;
mod options;
mod photos;
mod pipeline;
mod runner;

pub use error::{INSTALL_COLMAP, ProcessError};
pub use options::{CameraModel, Event, Input, Matcher, ProcessOptions, ProcessReport, Stage};
pub use photos::list_photos;
pub use pipeline::process;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::work_folder;

    #[test]
    fn missing_colmap_says_how_to_install_it() {
        let dir = tempfile::tempdir().unwrap();
        for n in ["a.png", "b.png"] {
            image::RgbImage::new(4, 4).save(dir.path().join(n)).unwrap();
        }
        let mut o = ProcessOptions::new(Input::Photos(dir.path().into()), dir.path().join("out"));
        o.colmap = "/nonexistent/colmap".into();
        let e = process(&o, &mut |_| {}).unwrap_err().to_string();
        assert!(
            e.contains("/nonexistent/colmap") && e.contains("apt-get install colmap"),
            "{e}"
        );
        assert!(!dir.path().join("out").exists());
        assert!(!dir.path().join("out.incomplete").exists());
    }

    #[test]
    fn existing_output_is_refused_and_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("scene");
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("keep.txt"), "mine").unwrap();
        let o = ProcessOptions::new(Input::Photos(dir.path().into()), &out);
        let e = process(&o, &mut |_| {}).unwrap_err().to_string();
        assert!(e.contains("already exists") && e.contains("scene"), "{e}");
        assert_eq!(
            std::fs::read_to_string(out.join("keep.txt")).unwrap(),
            "mine"
        );
        // A folder in the working folder's place that is not ours is not touched either.
        let taken = dir.path().join("other.incomplete");
        std::fs::create_dir(&taken).unwrap();
        let e = work_folder(&dir.path().join("other"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("other.incomplete"), "{e}");
        assert!(taken.is_dir());
        // A working folder of ours that a running process holds is refused, not cleared (a second
        // run on the same --out deleted the first's work and published its own photos under it).
        let out = dir.path().join("busy");
        let (work, lock) = work_folder(&out).unwrap();
        assert!(lock.is_some(), "this file system has locks");
        std::fs::write(work.join("images.txt"), "first run").unwrap();
        let e = work_folder(&out).unwrap_err().to_string();
        assert!(e.contains("another deepview process is building"), "{e}");
        assert!(work.join("images.txt").is_file());
        // Once its holder is gone (a killed run), the next run clears it.
        drop(lock);
        let (again, _lock) = work_folder(&out).unwrap();
        assert_eq!(again, work);
        assert!(!work.join("images.txt").exists());
    }
}
