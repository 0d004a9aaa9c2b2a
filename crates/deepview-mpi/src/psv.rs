//! The plane sweep volume: an image inverse-warped onto every MPI plane, with a validity channel.

use crate::warp::warp_image;
use deepview_geometry::{Camera, plane_homography};
use deepview_image::ImageF32;
use rayon::prelude::*;

/// `[D][H][W][C + 1]` in the reference camera's pixels: the image's C channels sampled on each plane, then
/// a validity channel (1 where the plane point projects inside the image, else 0 and the colour is 0).
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneSweepVolume {
    pub width: u32,
    pub height: u32,
    /// Channels per texel, validity included.
    pub channels: usize,
    pub depths: Vec<f64>,
    pub data: Vec<f32>,
}

impl PlaneSweepVolume {
    pub fn plane(&self, d: usize) -> &[f32] {
        let n = self.width as usize * self.height as usize * self.channels;
        &self.data[d * n..(d + 1) * n]
    }

    /// Plane `d` as an image (colour channels only).
    pub fn plane_image(&self, d: usize) -> ImageF32 {
        let c = self.channels - 1;
        let data = self
            .plane(d)
            .chunks_exact(self.channels)
            .flat_map(|p| p[..c].to_vec())
            .collect();
        ImageF32 {
            width: self.width,
            height: self.height,
            channels: c,
            data,
        }
    }
}

/// Sweep `image` (seen by `camera`) over the planes at `depths` of the `reference` camera.
pub fn plane_sweep(
    image: &ImageF32,
    camera: &Camera,
    reference: &Camera,
    depths: &[f64],
) -> PlaneSweepVolume {
    let (w, h, c) = (reference.width, reference.height, image.channels);
    let pixels = w as usize * h as usize;
    let mut data = vec![0.0f32; depths.len() * pixels * (c + 1)];
    data.par_chunks_mut(pixels * (c + 1))
        .zip(depths.par_iter())
        .for_each(|(plane, &depth)| {
            // Reference pixel -> image pixel through the plane.
            let hom = plane_homography(reference, camera, depth).to_row_major();
            let mut colour = vec![0.0f32; pixels * c];
            let mut valid = vec![0.0f32; pixels];
            warp_image(
                &image.data,
                image.width,
                image.height,
                c,
                hom,
                w,
                h,
                &mut colour,
                Some(&mut valid),
            );
            for ((o, col), v) in plane
                .chunks_exact_mut(c + 1)
                .zip(colour.chunks_exact(c))
                .zip(&valid)
            {
                o[..c].copy_from_slice(col);
                o[c] = *v;
            }
        });
    PlaneSweepVolume {
        width: w,
        height: h,
        channels: c + 1,
        depths: depths.to_vec(),
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};

    #[test]
    fn sweep_onto_own_camera_is_the_image_at_any_depth() {
        let cam = Camera::new(
            13,
            9,
            Intrinsics::new(11.0, 12.0, 6.3, 4.4),
            Pose::from_center(DMat3::from_rotation_z(0.4), DVec3::new(1.0, -2.0, 0.5)),
        );
        let mut img = ImageF32::new(13, 9, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 37) % 101) as f32 / 100.0;
        }
        let psv = plane_sweep(&img, &cam, &cam, &[100.0, 3.0, 0.7]);
        for d in 0..3 {
            assert_eq!(psv.plane_image(d), img);
            assert!(psv.plane(d).chunks_exact(4).all(|p| p[3] == 1.0));
        }
    }
}
