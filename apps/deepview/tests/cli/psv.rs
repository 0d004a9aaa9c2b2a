//! `deepview psv`: the plane sweep volume of a view onto its own camera.

use crate::common::{data, deepview, s};

#[test]
fn psv_of_a_fern_view_onto_its_own_camera_is_the_image() {
    let tmp = tempfile::tempdir().unwrap();
    let fern = data().join("llff/fern");
    let out = tmp.path().join("psv");
    let o = deepview(&[
        "psv",
        "--data",
        s(&fern),
        "--images",
        "images_8",
        "--view",
        "5",
        "--planes",
        "4",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = deepview_image::read_image(&fern.join("images_8/image005.png"), 3).unwrap();
    for d in 0..4 {
        let plane = deepview_image::read_image(&out.join(format!("psv_{d:03}.png")), 4).unwrap();
        assert_eq!(plane.to_rgb(), img, "plane {d}");
        assert!(plane.data.chunks_exact(4).all(|p| p[3] == 1.0));
    }
}
