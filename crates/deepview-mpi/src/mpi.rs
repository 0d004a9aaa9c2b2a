//! The MPI type: D RGBA planes in front of a reference camera, back to front, premultiplied colour.

use deepview_geometry::Camera;

/// A texel type of MPI layers: f32 or u8 premultiplied RGBA.
pub trait Texel: Copy + Default + Send + Sync + 'static {
    /// Premultiplied RGBA of texel `i` (in texels) as f32 in 0..1.
    fn rgba(layer: &[Self], i: usize) -> [f32; 4];
    /// The layer as bytes when texels are 8-bit (enables the SIMD kernel).
    fn as_bytes(layer: &[Self]) -> Option<&[u8]> {
        let _ = layer;
        None
    }
    /// A layer file's pixels (straight alpha, any bit depth) as premultiplied texels `[H][W][4]`.
    fn premultiplied(image: image::DynamicImage) -> Vec<Self>;
}

impl Texel for f32 {
    #[inline(always)]
    fn rgba(layer: &[f32], i: usize) -> [f32; 4] {
        let p = &layer[i * 4..i * 4 + 4];
        [p[0], p[1], p[2], p[3]]
    }

    /// Exact: the file's values (8 or 16 bit) times their alpha, in f32.
    fn premultiplied(image: image::DynamicImage) -> Vec<f32> {
        let mut data = image.into_rgba32f().into_raw();
        for p in data.chunks_exact_mut(4) {
            for k in 0..3 {
                p[k] *= p[3];
            }
        }
        data
    }
}

impl Texel for u8 {
    #[inline(always)]
    fn rgba(layer: &[u8], i: usize) -> [f32; 4] {
        let p = &layer[i * 4..i * 4 + 4];
        const S: f32 = 1.0 / 255.0;
        [
            p[0] as f32 * S,
            p[1] as f32 * S,
            p[2] as f32 * S,
            p[3] as f32 * S,
        ]
    }

    fn as_bytes(layer: &[u8]) -> Option<&[u8]> {
        Some(layer)
    }

    /// 8-bit colour times 8-bit alpha, rounded.
    fn premultiplied(image: image::DynamicImage) -> Vec<u8> {
        let mut px = image.into_rgba8().into_raw();
        for p in px.chunks_exact_mut(4) {
            let a = p[3] as u32;
            for c in &mut p[..3] {
                *c = ((*c as u32 * a + 127) / 255) as u8;
            }
        }
        px
    }
}

/// A multiplane image with texels `T` (f32 by default; [`MpiU8`] for rendering and the viewer).
///
/// `layers` is `[D][H][W][4]` (plane, row, column, premultiplied RGBA), plane 0 the farthest;
/// `depths[d]` is the depth of plane `d` along the reference camera's optical axis (decreasing).
#[derive(Clone, Debug, PartialEq)]
pub struct Mpi<T = f32> {
    pub camera: Camera,
    pub depths: Vec<f64>,
    pub layers: Vec<T>,
}

/// The same MPI with 8-bit premultiplied texels: a quarter of the memory traffic, used for real-time
/// rendering and the viewer.
pub type MpiU8 = Mpi<u8>;

impl<T: Texel> Mpi<T> {
    pub fn planes(&self) -> usize {
        self.depths.len()
    }

    pub fn plane_len(&self) -> usize {
        self.camera.width as usize * self.camera.height as usize * 4
    }

    /// Plane `d` as `[H][W][4]`.
    pub fn plane(&self, d: usize) -> &[T] {
        let n = self.plane_len();
        &self.layers[d * n..(d + 1) * n]
    }

    pub fn plane_mut(&mut self, d: usize) -> &mut [T] {
        let n = self.plane_len();
        &mut self.layers[d * n..(d + 1) * n]
    }
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
    pub fn to_f32(&self) -> Mpi {
        Mpi {
            camera: self.camera,
            depths: self.depths.clone(),
            layers: self.layers.iter().map(|&v| v as f32 / 255.0).collect(),
        }
    }
}
