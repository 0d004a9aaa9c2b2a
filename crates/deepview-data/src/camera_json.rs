//! Camera JSON files (`{"width","height","fx","fy","cx","cy","camera_from_world":[16 numbers, row-major]}`),
//! as `deepview info --camera` writes them and `render --camera` reads them.

use crate::DataError;
use deepview_geometry::{Camera, CameraJson};
use std::path::Path;

/// Read a camera JSON file; every error names the file.
pub fn read_camera_json(path: &Path) -> Result<Camera, DataError> {
    // (A byte order mark, which Windows editors write, is not JSON's: read_text drops it.)
    let text = deepview_image::read_text(path).map_err(|e| DataError::io(path, e))?;
    let json: CameraJson = serde_json::from_str(&text).map_err(|source| DataError::Json {
        path: path.into(),
        source,
    })?;
    json.to_camera()
        .map_err(|e| DataError::geometry(path, "invalid camera", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cam.json");
        assert!(
            read_camera_json(&p)
                .unwrap_err()
                .to_string()
                .contains("cam.json")
        );
        std::fs::write(&p, "{\"width\": 10,").unwrap();
        let e = read_camera_json(&p).unwrap_err().to_string();
        assert!(e.contains("cam.json") && e.contains("JSON"), "{e}");
        let cam = Camera::new(
            10,
            8,
            deepview_geometry::Intrinsics::new(10.0, 10.0, 5.0, 4.0),
            deepview_geometry::Pose::IDENTITY,
        );
        std::fs::write(&p, serde_json::to_string(&cam.to_json()).unwrap()).unwrap();
        assert_eq!(read_camera_json(&p).unwrap(), cam);
    }
}
