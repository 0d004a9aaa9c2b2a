//! The MPI type: D RGBA planes in front of a reference camera, back to front, premultiplied colour.

use deepview_geometry::Camera;

/// A multiplane image with f32 texels.
///
/// `layers` is `[D][H][W][4]` (plane, row, column, premultiplied RGBA), plane 0 the farthest;
/// `depths[d]` is the depth of plane `d` along the reference camera's optical axis (decreasing).
#[derive(Clone, Debug, PartialEq)]
pub struct Mpi {
    pub camera: Camera,
    pub depths: Vec<f64>,
    pub layers: Vec<f32>,
}

/// The same MPI with 8-bit premultiplied texels: a quarter of the memory traffic, used for real-time
/// rendering and the viewer.
#[derive(Clone, Debug, PartialEq)]
pub struct MpiU8 {
    pub camera: Camera,
    pub depths: Vec<f64>,
    pub layers: Vec<u8>,
}

impl Mpi {
    /// A fully transparent MPI.
    pub fn transparent(camera: Camera, depths: Vec<f64>) -> Self {
        let n = depths.len() * camera.width as usize * camera.height as usize * 4;
        Self {
            camera,
            depths,
            layers: vec![0.0; n],
        }
    }

    pub fn planes(&self) -> usize {
        self.depths.len()
    }

    pub fn plane_len(&self) -> usize {
        self.camera.width as usize * self.camera.height as usize * 4
    }

    /// Plane `d` as `[H][W][4]`.
    pub fn plane(&self, d: usize) -> &[f32] {
        let n = self.plane_len();
        &self.layers[d * n..(d + 1) * n]
    }

    pub fn plane_mut(&mut self, d: usize) -> &mut [f32] {
        let n = self.plane_len();
        &mut self.layers[d * n..(d + 1) * n]
    }

    /// Quantise to 8-bit premultiplied texels (colour clamped to alpha).
    pub fn to_u8(&self) -> MpiU8 {
        let layers = self
            .layers
            .chunks_exact(4)
            .flat_map(|p| {
                let a = p[3].clamp(0.0, 1.0);
                let q = |v: f32| (v.clamp(0.0, a) * 255.0 + 0.5) as u8;
                [q(p[0]), q(p[1]), q(p[2]), (a * 255.0 + 0.5) as u8]
            })
            .collect();
        MpiU8 {
            camera: self.camera,
            depths: self.depths.clone(),
            layers,
        }
    }
}

impl MpiU8 {
    pub fn planes(&self) -> usize {
        self.depths.len()
    }

    pub fn to_f32(&self) -> Mpi {
        Mpi {
            camera: self.camera,
            depths: self.depths.clone(),
            layers: self.layers.iter().map(|&v| v as f32 / 255.0).collect(),
        }
    }
}
