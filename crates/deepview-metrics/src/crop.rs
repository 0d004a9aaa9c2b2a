//! Border cropping before scoring, and the 8-bit round trip the official protocol implies.

use crate::MetricsError;
use deepview_image::ImageF32;

/// Pixels removed from each side of an image before it is scored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BorderCrop {
    pub left: u32,
    pub top: u32,
    pub right: u32,
    pub bottom: u32,
}

impl BorderCrop {
    pub fn uniform(n: u32) -> Self {
        Self {
            left: n,
            top: n,
            right: n,
            bottom: n,
        }
    }

    pub fn apply(&self, img: &ImageF32) -> Result<ImageF32, MetricsError> {
        crop_border(img, self.left, self.top, self.right, self.bottom)
    }
}

/// Remove `left`, `top`, `right`, `bottom` pixels from the sides of `img` (numpy `img[top:-bottom, left:-right]`).
///
/// Errors when nothing would be left.
pub fn crop_border(
    img: &ImageF32,
    left: u32,
    top: u32,
    right: u32,
    bottom: u32,
) -> Result<ImageF32, MetricsError> {
    let too_large = || MetricsError::CropTooLarge {
        left,
        top,
        right,
        bottom,
        width: img.width,
        height: img.height,
    };
    let w = img
        .width
        .checked_sub(left)
        .and_then(|v| v.checked_sub(right))
        .filter(|&v| v > 0)
        .ok_or_else(too_large)?;
    let h = img
        .height
        .checked_sub(top)
        .and_then(|v| v.checked_sub(bottom))
        .filter(|&v| v > 0)
        .ok_or_else(too_large)?;
    Ok(img.crop(left, top, w, h))
}

/// Round every value to the nearest of 0/255 .. 255/255 (clamped), as writing and re-reading an 8-bit PNG does.
///
/// The Spaces protocol scores saved PNGs, so a float prediction is quantised before scoring to compare like
/// with like.
pub fn quantize_u8(img: &ImageF32) -> ImageF32 {
    let data = img
        .data
        .iter()
        .map(|&v| deepview_image::to_u8(v) as f32 / 255.0)
        .collect();
    ImageF32 {
        width: img.width,
        height: img.height,
        channels: img.channels,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32) -> ImageF32 {
        let data = (0..w * h).map(|i| i as f32).collect();
        ImageF32::from_data(w, h, 1, data).unwrap()
    }

    #[test]
    fn crop_takes_the_right_window() {
        let img = ramp(6, 5);
        let c = crop_border(&img, 1, 2, 3, 1).unwrap();
        assert_eq!((c.width, c.height), (2, 2));
        // rows 2..4, columns 1..3 of value y*6+x
        assert_eq!(c.data, vec![13.0, 14.0, 19.0, 20.0]);
        assert_eq!(BorderCrop::uniform(0).apply(&img).unwrap(), img);
    }

    #[test]
    fn crop_too_large_is_an_error() {
        let img = ramp(6, 5);
        assert!(matches!(
            crop_border(&img, 3, 0, 3, 0),
            Err(MetricsError::CropTooLarge { .. })
        ));
        assert!(crop_border(&img, 0, 4, 0, 2).is_err());
        assert!(crop_border(&img, u32::MAX, 0, 0, 0).is_err());
    }

    #[test]
    fn quantisation_rounds_to_8_bit() {
        let img =
            ImageF32::from_data(3, 1, 1, vec![-0.5, 0.5, 100.0 / 255.0 + 0.4 / 255.0]).unwrap();
        assert_eq!(
            quantize_u8(&img).data,
            vec![0.0, 128.0 / 255.0, 100.0 / 255.0]
        );
    }
}
