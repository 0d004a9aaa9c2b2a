//! LLFF's MPI format (Fyusion/LLFF, `llff/inference/mpi_utils.py`: `MPI.save(binary=True)` writes it,
//! `load_mpi` and the OpenGL / CUDA viewers read it).
//!
//! `metadata.txt`, six lines of space-separated numbers:
//! ```text
//! H W D focal          # plane size, plane count, focal length in pixels (fx = fy, principal point centred)
//! r0 r1 r2             # camera-to-world column 0: camera right, in world coordinates
//! u0 u1 u2             # column 1: camera up
//! b0 b1 b2             # column 2: camera back (the camera looks along -b)
//! c0 c1 c2             # column 3: camera centre
//! far near             # LLFF's "inf_depth close_depth"
//! ```
//! (`MPI.save` turns LLFF's [down, right, back] pose columns into [right, up, back], i.e. OpenGL axes, so
//! the four pose lines are the columns of an OpenGL camera-to-world matrix.)
//!
//! `mpi.b`: raw `uint8` array `[D][H][W][4]`, straight (not premultiplied) RGBA. Plane order: LLFF renders
//! with `dispvals = linspace(1/far, 1/near, D)` and composites with a reverse exclusive cumprod, so plane 0
//! is the farthest: the same order as ours. Plane depths are therefore equally spaced in inverse depth
//! between `far` and `near`; an MPI with other spacing cannot be represented (export warns).
//!
//! Pixel convention: LLFF's renderer puts the principal point at `(W/2, H/2)` in integer-centred pixel
//! coordinates, half a pixel off ours; we read and write the centred principal point `(W/2, H/2)` of our
//! convention and export warns when the MPI's principal point is not centred or `fx != fy`.

use super::straight::{
    ExportReport, StraightMpi, check_planes, inverse_depth_spacing_error, numbers,
};
use crate::error::{MpiError, invalid, read_err, write_err};
use crate::io::check_depths;
use deepview_geometry::convention::{opengl_c2w_to_pose, pose_to_opengl_c2w};
use deepview_geometry::{Camera, Intrinsics, PlaneSpacing, plane_depths};
use deepview_image::write_atomic;
use std::path::Path;

/// Write `mpi` as LLFF `metadata.txt` + `mpi.b` in the folder `out`.
pub fn write(out: &Path, mpi: &StraightMpi) -> Result<ExportReport, MpiError> {
    check_planes(out, mpi)?;
    // metadata.txt holds a near and a far depth: one plane has no range, and would not import back.
    if mpi.depths.len() < 2 {
        return Err(crate::error::invalid(
            out,
            "LLFF's format needs at least 2 planes (its metadata is a depth range); this MPI has 1",
        ));
    }
    let cam = &mpi.camera;
    let k = cam.intrinsics;
    let mut report = ExportReport::default();
    if (k.fx - k.fy).abs() > 1e-6 * k.fx {
        report.warnings.push(format!(
            "LLFF stores one focal length: fx {} and fy {} differ, writing fx",
            k.fx, k.fy
        ));
    }
    let (cx, cy) = (cam.width as f64 / 2.0, cam.height as f64 / 2.0);
    if (k.cx - cx).abs() > 1e-6 || (k.cy - cy).abs() > 1e-6 {
        report.warnings.push(format!(
            "LLFF assumes a centred principal point ({cx}, {cy}); this MPI's is ({}, {}) and is dropped",
            k.cx, k.cy
        ));
    }
    let err = inverse_depth_spacing_error(&mpi.depths);
    if err > 1e-6 {
        report.warnings.push(format!(
            "LLFF planes are equally spaced in inverse depth; these depths deviate by {:.2e} of the range",
            err
        ));
    }
    std::fs::create_dir_all(out).map_err(write_err(out))?;
    let m = pose_to_opengl_c2w(&cam.pose);
    let far = mpi.depths[0];
    let near = mpi.depths[mpi.depths.len() - 1];
    let mut text = format!(
        "{} {} {} {}\n",
        cam.height,
        cam.width,
        mpi.depths.len(),
        k.fx
    );
    for j in 0..4 {
        // `+ 0.0` turns -0 into 0 for tidier files.
        text += &format!("{} {} {}\n", m[j] + 0.0, m[4 + j] + 0.0, m[8 + j] + 0.0);
    }
    text += &format!("{far} {near}\n");
    let bin = out.join("mpi.b");
    write_atomic(&bin, &mpi.planes.concat())?;
    let meta = out.join("metadata.txt");
    write_atomic(&meta, text.as_bytes())?;
    report.add(bin)?;
    report.add(meta)?;
    Ok(report)
}

/// `metadata.txt`'s lines and its first one's numbers: height, width, plane count and focal length.
fn header(meta_path: &Path) -> Result<(Vec<String>, usize, usize, usize, f64), MpiError> {
    let text = deepview_image::read_text(meta_path).map_err(read_err(meta_path))?;
    let lines: Vec<String> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(str::to_string)
        .collect();
    if lines.len() < 6 {
        return Err(invalid(
            meta_path,
            format!(
                "expected 6 lines (size, 4 pose columns, depth bounds), got {}",
                lines.len()
            ),
        ));
    }
    let head = numbers(meta_path, 0, &lines[0], 4)?;
    let as_count = |v: f64, what: &str| -> Result<usize, MpiError> {
        if v >= 1.0 && v.fract() == 0.0 && v < 1e6 {
            Ok(v as usize)
        } else {
            Err(invalid(
                meta_path,
                format!("line 1: {what} must be a positive integer, got {v}"),
            ))
        }
    };
    let (h, w, d) = (
        as_count(head[0], "height")?,
        as_count(head[1], "width")?,
        as_count(head[2], "plane count")?,
    );
    Ok((lines, h, w, d, head[3]))
}

/// Width, height and plane count of an LLFF MPI folder, from `metadata.txt` alone.
pub fn size(dir: &Path) -> Result<(u32, u32, usize), MpiError> {
    let (_, h, w, d, _) = header(&dir.join("metadata.txt"))?;
    Ok((w as u32, h as u32, d))
}

/// Read an LLFF MPI folder (`metadata.txt` + `mpi.b`).
pub fn read(dir: &Path) -> Result<StraightMpi, MpiError> {
    let meta_path = dir.join("metadata.txt");
    let (lines, h, w, d, focal) = header(&meta_path)?;
    let mut m = [0.0; 16];
    for j in 0..4 {
        let col = numbers(&meta_path, j + 1, &lines[j + 1], 3)?;
        m[j] = col[0];
        m[4 + j] = col[1];
        m[8 + j] = col[2];
    }
    m[15] = 1.0;
    let pose =
        opengl_c2w_to_pose(&m).map_err(|e| invalid(&meta_path, format!("camera pose: {e}")))?;
    let bounds = numbers(&meta_path, 5, &lines[5], 2)?;
    let (far, near) = (bounds[0], bounds[1]);
    let depths = plane_depths(near, far, d, PlaneSpacing::InverseDepth)
        .map_err(|e| invalid(&meta_path, format!("line 6 (far near): {e}")))?;
    // A tiny near depth (e.g. 1e-320) passes plane_depths but its inverse overflows to depths of 0.
    check_depths(&meta_path, &depths)?;
    let camera = Camera::new(
        w as u32,
        h as u32,
        Intrinsics::centred(focal, w as u32, h as u32),
        pose,
    );
    camera
        .validate()
        .map_err(|e| invalid(&meta_path, e.to_string()))?;
    let bin_path = dir.join("mpi.b");
    let plane_len = w * h * 4;
    // The size first: a file that cannot be these planes is not read (a sparse file of terabytes).
    let len = std::fs::metadata(&bin_path)
        .map_err(read_err(&bin_path))?
        .len();
    if len != (plane_len * d) as u64 {
        return Err(invalid(
            &bin_path,
            format!(
                "has {len} bytes, metadata.txt says {d} planes of {w}x{h}x4 = {} bytes",
                plane_len * d
            ),
        ));
    }
    let bytes = std::fs::read(&bin_path).map_err(read_err(&bin_path))?;
    if bytes.len() != plane_len * d {
        return Err(invalid(
            &bin_path,
            format!(
                "has {} bytes, metadata.txt says {d} planes of {w}x{h}x4 = {} bytes",
                bytes.len(),
                plane_len * d
            ),
        ));
    }
    let planes = bytes.chunks_exact(plane_len).map(|c| c.to_vec()).collect();
    Ok(StraightMpi {
        camera,
        depths,
        planes,
    })
}
