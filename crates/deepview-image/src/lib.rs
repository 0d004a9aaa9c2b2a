//! Float images (interleaved channels, values in 0..1), reading PNG/JPEG, and atomic writes.
//!
//! Every file this project writes goes through [`write_atomic`]: a temporary file beside the target, then
//! a rename, so an interrupted run never leaves a half-written result in place of an earlier one.

mod atomic;
pub mod child;

pub use atomic::{
    Durability, TEMP_NAME_EXTRA, TempLock, TempName, is_file_browser_clutter, is_held, is_temp_of,
    lock_file, lock_temp, parse_temp, temp_path, temp_stem, temp_token, write_atomic,
    write_atomic_with,
};

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("cannot read image {path}: {source}")]
    Read {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot encode {path}: {source}")]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("cannot read image {path}: {msg}")]
    Corrupt { path: PathBuf, msg: String },
    #[error("{0}")]
    Invalid(String),
}

/// An image with `channels` interleaved f32 channels per pixel, row-major, values nominally in 0..1.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageF32 {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn new(width: u32, height: u32, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; width as usize * height as usize * channels],
        }
    }

    pub fn from_data(
        width: u32,
        height: u32,
        channels: usize,
        data: Vec<f32>,
    ) -> Result<Self, ImageError> {
        if data.len() != width as usize * height as usize * channels {
            return Err(ImageError::Invalid(format!(
                "image data has {} values, expected {}x{}x{}",
                data.len(),
                width,
                height,
                channels
            )));
        }
        Ok(Self {
            width,
            height,
            channels,
            data,
        })
    }

    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let i = (y as usize * self.width as usize + x as usize) * self.channels;
        &self.data[i..i + self.channels]
    }

    pub fn pixel_mut(&mut self, x: u32, y: u32) -> &mut [f32] {
        let i = (y as usize * self.width as usize + x as usize) * self.channels;
        &mut self.data[i..i + self.channels]
    }

    /// The first three channels (drops alpha or validity channels).
    pub fn to_rgb(&self) -> ImageF32 {
        if self.channels == 3 {
            return self.clone();
        }
        let mut out = ImageF32::new(self.width, self.height, 3);
        for (o, i) in out
            .data
            .chunks_exact_mut(3)
            .zip(self.data.chunks_exact(self.channels))
        {
            for c in 0..3 {
                o[c] = i[c.min(self.channels - 1)];
            }
        }
        out
    }

    /// Crop `[x0, x0+w) x [y0, y0+h)` (must lie inside the image).
    pub fn crop(&self, x0: u32, y0: u32, w: u32, h: u32) -> ImageF32 {
        assert!(
            x0 + w <= self.width && y0 + h <= self.height,
            "crop outside the image"
        );
        let mut out = ImageF32::new(w, h, self.channels);
        let c = self.channels;
        for y in 0..h as usize {
            let src = ((y0 as usize + y) * self.width as usize + x0 as usize) * c;
            out.data[y * w as usize * c..(y + 1) * w as usize * c]
                .copy_from_slice(&self.data[src..src + w as usize * c]);
        }
        out
    }

    /// Box-filter downscale by an integer factor (sizes rounded down).
    pub fn downscale(&self, factor: u32) -> ImageF32 {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h, c) = (self.width / factor, self.height / factor, self.channels);
        let mut out = ImageF32::new(w, h, c);
        let norm = 1.0 / (factor * factor) as f32;
        for y in 0..h {
            for x in 0..w {
                let o = (y as usize * w as usize + x as usize) * c;
                for dy in 0..factor {
                    for dx in 0..factor {
                        let p = self.pixel(x * factor + dx, y * factor + dy);
                        for k in 0..c {
                            out.data[o + k] += p[k] * norm;
                        }
                    }
                }
            }
        }
        out
    }

    pub fn is_finite(&self) -> bool {
        self.data.iter().all(|v| v.is_finite())
    }

    /// 8-bit interleaved bytes (clamped, rounded).
    pub fn to_u8(&self) -> Vec<u8> {
        self.data.iter().map(|&v| to_u8(v)).collect()
    }
}

pub fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// Decode an image file completely, or refuse it: a truncated or corrupt JPEG is an error (the `image`
/// crate's lenient decoder would fill the missing rows with grey), as is a PNG without its end chunk.
pub fn decode_file(path: &Path) -> Result<image::DynamicImage, ImageError> {
    let read_err = |e: std::io::Error| ImageError::Read {
        path: path.into(),
        source: image::ImageError::IoError(e),
    };
    refuse_special(path, "an image file").map_err(read_err)?;
    let bytes = std::fs::read(path).map_err(read_err)?;
    let corrupt = |msg: String| ImageError::Corrupt {
        path: path.into(),
        msg,
    };
    // HEIC/HEIF (an iPhone's photos): an ISO box `ftyp` with its brand, which `image` does not know.
    if bytes.get(4..8) == Some(b"ftyp")
        && let Some(brand) = bytes.get(8..12)
        && [
            b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1",
        ]
        .iter()
        .any(|b| &b[..] == brand)
    {
        return Err(corrupt(
            "is a HEIC/HEIF file, which deepview does not read: convert it to JPEG or PNG".into(),
        ));
    }
    let format = image::guess_format(&bytes).map_err(|e| ImageError::Read {
        path: path.into(),
        source: e,
    })?;
    match format {
        image::ImageFormat::Jpeg => {
            use zune_core::bytestream::ZCursor;
            use zune_core::colorspace::ColorSpace;
            let options = zune_core::options::DecoderOptions::default()
                .set_strict_mode(true)
                .jpeg_set_out_colorspace(ColorSpace::RGB);
            let mut dec =
                zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(&bytes[..]), options);
            let px = dec
                .decode()
                .map_err(|e| corrupt(format!("truncated or corrupt JPEG ({e:?})")))?;
            let (w, h) = dec
                .dimensions()
                .ok_or_else(|| corrupt("JPEG without a size".into()))?;
            if !jpeg_complete(&bytes) {
                return Err(corrupt(
                    "truncated or malformed JPEG (its segments do not reach an end-of-image \
                     marker FF D9)"
                        .into(),
                ));
            }
            let img = image::RgbImage::from_raw(w as u32, h as u32, px)
                .ok_or_else(|| corrupt("truncated or corrupt JPEG (short pixel data)".into()))?;
            Ok(image::DynamicImage::ImageRgb8(img))
        }
        image::ImageFormat::Png if !png_complete(&bytes) => Err(corrupt(
            "truncated PNG (its chunks do not reach a complete IEND chunk)".into(),
        )),
        f if !f.reading_enabled() => Err(corrupt(format!(
            "is a {} file, which deepview does not read: convert it to PNG or JPEG",
            format!("{f:?}").to_uppercase()
        ))),
        f => image::load_from_memory_with_format(&bytes, f).map_err(|e| match e {
            // The decoder's memory limit: say how large the image is and what to do.
            image::ImageError::Limits(_) => match image_size(path) {
                Ok((w, h)) => corrupt(format!(
                    "is {w}x{h}: larger than an image deepview decodes (512 MiB of pixels); downscale it \
                     first"
                )),
                Err(_) => ImageError::Read {
                    path: path.into(),
                    source: e,
                },
            },
            e => ImageError::Read {
                path: path.into(),
                source: e,
            },
        }),
    }
}

/// The most a small text file deepview reads (`mpi.json`, a camera, a camera path) may hold.
pub const TEXT_LIMIT: u64 = 64 << 20;

/// Read the small text file `path` (JSON: `mpi.json`, cameras, camera paths) without a byte order
/// mark, refusing a pipe, socket or device (reading a pipe would wait for a writer for ever, a device
/// like `/dev/zero` would fill the memory) and a file over [`TEXT_LIMIT`] bytes.
pub fn read_text(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    refuse_special(path, "a text file")?;
    let mut text = String::new();
    std::fs::File::open(path)?
        .take(TEXT_LIMIT + 1)
        .read_to_string(&mut text)?;
    if text.len() as u64 > TEXT_LIMIT {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "larger than {} MiB, more than such a file holds",
                TEXT_LIMIT >> 20
            ),
        ));
    }
    Ok(match text.strip_prefix('\u{feff}') {
        Some(t) => t.to_string(),
        None => text,
    })
}

/// `path` as a file argument of ffmpeg: ffmpeg reads `NAME:` at the start of a relative path as a
/// protocol (`a:b.mp4` failed with "Protocol not found"), so a relative path starts with `./`.
pub fn ffmpeg_file_arg(path: &Path) -> std::ffi::OsString {
    if path.is_absolute() || path.starts_with(".") || path.starts_with("..") {
        path.as_os_str().to_owned()
    } else {
        Path::new(".").join(path).into_os_string()
    }
}

/// An error for a pipe, socket or device where an image file should be: opening a pipe would wait
/// for a writer for ever.
pub fn refuse_special(path: &Path, expected: &str) -> std::io::Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() && !m.is_dir() => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("not a regular file (a pipe, socket or device), expected {expected}"),
        )),
        _ => Ok(()),
    }
}

/// Whether a PNG file holds its chunks up to a complete IEND chunk (its CRC included), walked by
/// their lengths: anything after IEND (data some cameras and apps append) is allowed.
fn png_complete(bytes: &[u8]) -> bool {
    let mut at = 8usize;
    while let Some(head) = bytes.get(at..at + 8) {
        let len = u32::from_be_bytes([head[0], head[1], head[2], head[3]]) as usize;
        // Length, type, data and CRC.
        let Some(end) = at.checked_add(12).and_then(|e| e.checked_add(len)) else {
            return false;
        };
        if end > bytes.len() {
            return false;
        }
        if &head[4..8] == b"IEND" {
            return true;
        }
        at = end;
    }
    false
}

/// Whether a JPEG file holds its segments and scans up to the end-of-image marker (FF D9), walked by
/// the segments' lengths and over each scan's entropy-coded data: an EXIF thumbnail's own FF D9 is
/// skipped with its segment, and anything after the image's end (a phone's motion-photo video) is
/// allowed.
fn jpeg_complete(bytes: &[u8]) -> bool {
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    let mut at = 2usize;
    loop {
        // A marker: FF (fill bytes FF allowed) then its code.
        if bytes.get(at) != Some(&0xFF) {
            return false;
        }
        while bytes.get(at) == Some(&0xFF) {
            at += 1;
        }
        let Some(&code) = bytes.get(at) else {
            return false;
        };
        at += 1;
        match code {
            0xD9 => return true,
            // Standalone markers: restarts, TEM.
            0xD0..=0xD7 | 0x01 => continue,
            _ => {}
        }
        let Some(len) = bytes
            .get(at..at + 2)
            .map(|l| u16::from_be_bytes([l[0], l[1]]) as usize)
        else {
            return false;
        };
        if len < 2 || at + len > bytes.len() {
            return false;
        }
        at += len;
        if code == 0xDA {
            // A scan's entropy-coded data runs to the next marker other than a stuffed zero or a
            // restart.
            loop {
                let Some(p) = bytes[at..].iter().position(|&b| b == 0xFF) else {
                    return false;
                };
                at += p;
                match bytes.get(at + 1) {
                    None => return false,
                    Some(0x00 | 0xD0..=0xD7 | 0xFF) => at += 1,
                    Some(_) => break,
                }
            }
        }
    }
}

/// Read a photo as RGB for the views of a scene. Where it has transparent pixels (alpha below 1, or
/// a PNG's transparent colour) they are composited onto white, as NeRF tools read Blender's
/// synthetic scenes (transparent backgrounds): dropping the alpha would take the colour stored
/// under it (often black) for the scene's.
pub fn read_photo(path: &Path) -> Result<ImageF32, ImageError> {
    let img = decode_file(path)?;
    let (w, h) = (img.width(), img.height());
    if !img.color().has_alpha() {
        return ImageF32::from_data(w, h, 3, img.into_rgb32f().into_raw());
    }
    let rgba = img.into_rgba32f().into_raw();
    let data = rgba
        .chunks_exact(4)
        .flat_map(|p| {
            let a = p[3];
            [0, 1, 2].map(|c| p[c] * a + (1.0 - a))
        })
        .collect();
    ImageF32::from_data(w, h, 3, data)
}

/// Read a PNG or JPEG (8 or 16 bit) as RGB (`channels = 3`) or RGBA (`channels = 4`, straight alpha),
/// decoded completely ([`decode_file`]).
pub fn read_image(path: &Path, channels: usize) -> Result<ImageF32, ImageError> {
    let img = decode_file(path)?;
    let (w, h) = (img.width(), img.height());
    let data: Vec<f32> = match channels {
        3 => img.into_rgb32f().into_raw(),
        4 => img.into_rgba32f().into_raw(),
        1 => img
            .into_luma16()
            .into_raw()
            .into_iter()
            .map(|v| v as f32 / 65535.0)
            .collect(),
        _ => {
            return Err(ImageError::Invalid(format!(
                "cannot read {channels} channels"
            )));
        }
    };
    ImageF32::from_data(w, h, channels, data)
}

/// Image size without decoding the pixels. A PNG's size comes straight from its IHDR chunk, so that a
/// header announcing a huge image is reported with its size (the decoder's memory limit would refuse it
/// without saying why).
pub fn image_size(path: &Path) -> Result<(u32, u32), ImageError> {
    refuse_special(path, "an image file").map_err(|e| ImageError::Read {
        path: path.into(),
        source: image::ImageError::IoError(e),
    })?;
    let mut head = [0u8; 24];
    if let Ok(mut f) = std::fs::File::open(path)
        && std::io::Read::read_exact(&mut f, &mut head).is_ok()
        && head[..8] == *b"\x89PNG\r\n\x1a\n"
        && head[12..16] == *b"IHDR"
    {
        let w = u32::from_be_bytes([head[16], head[17], head[18], head[19]]);
        let h = u32::from_be_bytes([head[20], head[21], head[22], head[23]]);
        if w > 0 && h > 0 {
            return Ok((w, h));
        }
    }
    image::image_dimensions(path).map_err(|e| ImageError::Read {
        path: path.into(),
        source: e,
    })
}

/// The mark deepview puts in the images and videos it writes (a PNG `tEXt` chunk `Software`, a JPEG
/// comment segment, a GIF comment extension before its trailer, an MP4's `comment` metadata), so that
/// a later run replaces an output of its own but never a user's photo or video of the same name.
pub const MARK: &[u8; 8] = b"deepview";

/// The GIF comment extension holding [`MARK`] (with its block terminator), written before the trailer.
pub const GIF_MARK: [u8; 12] = [
    0x21, 0xFE, 8, b'd', b'e', b'e', b'p', b'v', b'i', b'e', b'w', 0x00,
];

/// CRC-32 (ISO-HDLC, PNG's) of `bytes`.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// Whether the PNG bytes `head` (from the start of the file) have deepview's `tEXt` chunk before
/// their image data.
fn png_marked(head: &[u8]) -> bool {
    let mut at = 8usize;
    while let Some(c) = head.get(at..at + 8) {
        let len = u32::from_be_bytes([c[0], c[1], c[2], c[3]]) as usize;
        match &c[4..8] {
            b"tEXt" => {
                let want = [&b"Software\0"[..], &MARK[..]].concat();
                if head.get(at + 8..at + 8 + len) == Some(&want[..]) {
                    return true;
                }
            }
            b"IDAT" | b"IEND" => return false,
            _ => {}
        }
        let Some(next) = at.checked_add(12).and_then(|a| a.checked_add(len)) else {
            return false;
        };
        at = next;
    }
    false
}

/// A PNG file's bytes that deepview copies into an output of its own (a web viewer folder), given its
/// mark where they lack it; anything else as it is.
pub fn with_mark(bytes: Vec<u8>) -> Vec<u8> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") && !png_marked(&bytes) {
        mark_png(bytes)
    } else {
        bytes
    }
}

/// `png` (a whole PNG file) with a `tEXt` chunk `Software` = [`MARK`] after its IHDR chunk.
fn mark_png(png: Vec<u8>) -> Vec<u8> {
    const IHDR_END: usize = 8 + 12 + 13;
    if png.len() < IHDR_END || &png[12..16] != b"IHDR" {
        return png;
    }
    let mut body = b"tEXtSoftware\0".to_vec();
    body.extend_from_slice(MARK);
    let mut out = Vec::with_capacity(png.len() + body.len() + 8);
    out.extend_from_slice(&png[..IHDR_END]);
    out.extend_from_slice(&((body.len() - 4) as u32).to_be_bytes());
    out.extend_from_slice(&body);
    out.extend_from_slice(&crc32(&body).to_be_bytes());
    out.extend_from_slice(&png[IHDR_END..]);
    out
}

/// `jpeg` (a whole JPEG file) with a comment segment holding [`MARK`] after its leading APPn segments
/// (the JFIF header stays first, where JFIF readers look for it).
fn mark_jpeg(jpeg: Vec<u8>) -> Vec<u8> {
    if !jpeg.starts_with(&[0xFF, 0xD8]) {
        return jpeg;
    }
    let mut at = 2usize;
    while let Some(&[0xFF, code, hi, lo]) = jpeg.get(at..at + 4) {
        if !(0xE0..=0xEF).contains(&code) {
            break;
        }
        at += 2 + u16::from_be_bytes([hi, lo]) as usize;
    }
    let at = at.min(jpeg.len());
    let mut out = Vec::with_capacity(jpeg.len() + 12);
    out.extend_from_slice(&jpeg[..at]);
    out.extend_from_slice(&[0xFF, 0xFE]);
    out.extend_from_slice(&((MARK.len() + 2) as u16).to_be_bytes());
    out.extend_from_slice(MARK);
    out.extend_from_slice(&jpeg[at..]);
    out
}

/// Whether the file at `path` carries [`MARK`] where deepview writes it: a PNG's `tEXt` chunk before
/// its image data, a JPEG's comment segment before its first scan, a GIF's comment extension before
/// its trailer, or the metadata in the first MiB of an MP4 (written with `+faststart`) or a Matroska
/// file. `false` for anything else, a user's photo or video included.
pub fn written_by_deepview(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    // The mark of an image sits in its first chunks or segments (after IHDR, after deepview's own
    // JFIF header): 64 KiB hold it; only a video's metadata may lie deeper, within the first MiB.
    let mut head = Vec::with_capacity(1 << 16);
    if (&mut f).take(1 << 16).read_to_end(&mut head).is_err() {
        return false;
    }
    if (head.get(4..8) == Some(b"ftyp") || head.starts_with(&[0x1A, 0x45, 0xDF, 0xA3]))
        && (&mut f)
            .take((1 << 20) - (1 << 16))
            .read_to_end(&mut head)
            .is_err()
    {
        return false;
    }
    if head.starts_with(b"\x89PNG\r\n\x1a\n") {
        return png_marked(&head);
    }
    if head.starts_with(&[0xFF, 0xD8]) {
        let mut at = 2usize;
        while let Some(&[0xFF, code, hi, lo]) = head.get(at..at + 4) {
            let len = u16::from_be_bytes([hi, lo]) as usize;
            if code == 0xFE && head.get(at + 4..at + 2 + len) == Some(&MARK[..]) {
                return true;
            }
            if code == 0xDA || len < 2 {
                return false;
            }
            at += 2 + len;
        }
        return false;
    }
    if head.starts_with(b"GIF8") {
        let mut tail = [0u8; GIF_MARK.len() + 1];
        return f.seek(SeekFrom::End(-(tail.len() as i64))).is_ok()
            && f.read_exact(&mut tail).is_ok()
            && tail[..GIF_MARK.len()] == GIF_MARK
            && tail[GIF_MARK.len()] == 0x3B;
    }
    // MP4/MOV (`ftyp` box) and Matroska (EBML header): ffmpeg's `comment` tag near the start.
    (head.get(4..8) == Some(b"ftyp") || head.starts_with(&[0x1A, 0x45, 0xDF, 0xA3]))
        && head.windows(MARK.len()).any(|w| w == MARK)
}

fn encode_png(
    path: &Path,
    width: u32,
    height: u32,
    color: image::ExtendedColorType,
    bytes: &[u8],
) -> Result<Vec<u8>, ImageError> {
    use image::ImageEncoder;
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut buf,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(bytes, width, height, color)
    .map_err(|e| ImageError::Encode {
        path: path.into(),
        source: e,
    })?;
    Ok(mark_png(buf))
}

/// Write 8-bit interleaved bytes (1, 3 or 4 channels) as PNG, atomically.
pub fn write_png_u8(
    path: &Path,
    width: u32,
    height: u32,
    channels: usize,
    bytes: &[u8],
) -> Result<(), ImageError> {
    let color = match channels {
        1 => image::ExtendedColorType::L8,
        3 => image::ExtendedColorType::Rgb8,
        4 => image::ExtendedColorType::Rgba8,
        _ => {
            return Err(ImageError::Invalid(format!(
                "cannot write {channels} channels as PNG"
            )));
        }
    };
    let buf = encode_png(path, width, height, color, bytes)?;
    write_atomic(path, &buf)
}

/// Write a float image (its first three channels, values clamped to 0..1) as a JPEG of `quality`
/// (1..=100), atomically.
pub fn write_jpeg(path: &Path, img: &ImageF32, quality: u8) -> Result<(), ImageError> {
    use image::ImageEncoder;
    let rgb = img.to_rgb().to_u8();
    let mut buf = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, quality.clamp(1, 100))
        .write_image(&rgb, img.width, img.height, image::ExtendedColorType::Rgb8)
        .map_err(|e| ImageError::Encode {
            path: path.into(),
            source: e,
        })?;
    write_atomic(path, &mark_jpeg(buf))
}

/// Write a float image (1, 3 or 4 channels, values clamped to 0..1) as an 8-bit PNG, atomically.
pub fn write_png(path: &Path, img: &ImageF32) -> Result<(), ImageError> {
    write_png_u8(path, img.width, img.height, img.channels, &img.to_u8())
}

/// Write one channel of 16-bit values as a grayscale PNG, atomically.
pub fn write_png_u16(
    path: &Path,
    width: u32,
    height: u32,
    values: &[u16],
) -> Result<(), ImageError> {
    // The encoder takes native-endian u16 samples and writes PNG's big-endian itself.
    let native: Vec<u8> = values.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let buf = encode_png(path, width, height, image::ExtendedColorType::L16, &native)?;
    write_atomic(path, &buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A named pipe at `path` (no writer: opening it to read would wait for ever).
    #[cfg(unix)]
    fn fifo(path: &Path) {
        let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    #[cfg(unix)]
    #[test]
    fn a_pipe_named_as_an_image_is_an_error_not_a_wait() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("layer_000.png");
        fifo(&p);
        // Opening the pipe would block this test for ever (no writer).
        for e in [
            image_size(&p).unwrap_err().to_string(),
            read_image(&p, 4).unwrap_err().to_string(),
        ] {
            assert!(
                e.contains("layer_000.png") && e.contains("not a regular file"),
                "{e}"
            );
        }
    }

    /// Small text files: a pipe (no writer: opening it would wait for ever) and a device that never
    /// ends (`/dev/zero`, through a link) are errors at once, a file over the limit is refused, a byte
    /// order mark is dropped.
    #[cfg(unix)]
    #[test]
    fn text_files_are_read_bounded_and_never_wait() {
        let dir = tempfile::tempdir().unwrap();
        let pipe = dir.path().join("mpi.json");
        fifo(&pipe);
        let e = read_text(&pipe).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        let zero = dir.path().join("camera.json");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        let e = read_text(&zero).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        let big = dir.path().join("big.json");
        let f = std::fs::File::create(&big).unwrap();
        f.set_len(TEXT_LIMIT + 1).unwrap();
        let e = read_text(&big).unwrap_err().to_string();
        assert!(e.contains("larger than 64 MiB"), "{e}");
        let bom = dir.path().join("bom.json");
        std::fs::write(&bom, "\u{feff}{\"a\": 1}").unwrap();
        assert_eq!(read_text(&bom).unwrap(), "{\"a\": 1}");
    }

    #[test]
    fn png_round_trip_8_and_16_bit() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = ImageF32::new(5, 3, 4);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = (i % 256) as f32 / 255.0;
        }
        let p = dir.path().join("a.png");
        write_png(&p, &img).unwrap();
        let back = read_image(&p, 4).unwrap();
        assert_eq!(back, img);
        let vals: Vec<u16> = (0..15).map(|i| i * 4000).collect();
        let p16 = dir.path().join("d.png");
        write_png_u16(&p16, 5, 3, &vals).unwrap();
        let back = read_image(&p16, 1).unwrap();
        let got: Vec<u16> = back
            .data
            .iter()
            .map(|v| (v * 65535.0).round() as u16)
            .collect();
        assert_eq!(got, vals);
        // No temporary files left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn missing_and_corrupt_files_name_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("nope.png");
        let e = read_image(&p, 3).unwrap_err().to_string();
        assert!(e.contains("nope.png"), "{e}");
        let bad = dir.path().join("bad.png");
        std::fs::write(&bad, b"\x89PNG\r\n\x1a\nthis is not a png").unwrap();
        let e = read_image(&bad, 3).unwrap_err().to_string();
        assert!(e.contains("bad.png"), "{e}");
    }

    #[test]
    fn truncated_images_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = ImageF32::new(64, 48, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 37) % 251) as f32 / 251.0;
        }
        for (name, write) in [
            (
                "a.jpg",
                write_jpeg as fn(&Path, &ImageF32) -> Result<(), ImageError>,
            ),
            ("a.png", write_png),
        ] {
            let p = dir.path().join(name);
            write(&p, &img).unwrap();
            let full = read_image(&p, 3).unwrap();
            assert_eq!((full.width, full.height), (64, 48));
            let bytes = std::fs::read(&p).unwrap();
            for keep in [bytes.len() / 2, bytes.len() - 2] {
                let t = dir.path().join(format!("t{keep}_{name}"));
                std::fs::write(&t, &bytes[..keep]).unwrap();
                let e = read_image(&t, 3).unwrap_err().to_string();
                assert!(e.contains(t.file_name().unwrap().to_str().unwrap()), "{e}");
            }
        }
    }

    fn write_jpeg(path: &Path, img: &ImageF32) -> Result<(), ImageError> {
        super::write_jpeg(path, img, 90)
    }

    /// Data after a complete image (a phone's motion-photo video after a JPEG, an app's bytes after
    /// a PNG's IEND) is allowed; an image cut short inside its data is refused even where an EXIF
    /// thumbnail's own end marker lies within the file's last bytes.
    #[test]
    fn data_after_the_end_is_allowed_and_thumbnails_do_not_end_an_image() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = ImageF32::new(64, 48, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 53) % 241) as f32 / 241.0;
        }
        let jpg = dir.path().join("a.jpg");
        write_jpeg(&jpg, &img).unwrap();
        let png = dir.path().join("a.png");
        write_png(&png, &img).unwrap();
        for (p, trailer) in [(&jpg, 100_000), (&png, 5_000)] {
            let mut bytes = std::fs::read(p).unwrap();
            let want = read_image(p, 3).unwrap();
            // Not zeros only: a video's bytes hold FF and chunk-like words.
            bytes.extend((0..trailer).map(|i| (i * 7919 % 256) as u8));
            let t = dir.path().join(format!(
                "trailer_{}",
                p.file_name().unwrap().to_str().unwrap()
            ));
            std::fs::write(&t, &bytes).unwrap();
            assert!(read_image(&t, 3).unwrap() == want, "{}", t.display());
        }
        // A JPEG with an APP1 segment holding a thumbnail (FF D8 ... FF D9), cut inside its scan:
        // the thumbnail's end marker, within the file's last bytes, does not end the image.
        let bytes = std::fs::read(&jpg).unwrap();
        let mut app1 = vec![0xFF, 0xE1];
        let thumb: &[u8] = b"Exif\0\0\xFF\xD8thumbnail\xFF\xD9";
        app1.extend(((thumb.len() + 2) as u16).to_be_bytes());
        app1.extend(thumb);
        let mut full = bytes[..2].to_vec();
        full.extend(&app1);
        full.extend(&bytes[2..]);
        let whole = dir.path().join("whole.jpg");
        std::fs::write(&whole, &full).unwrap();
        assert!(read_image(&whole, 3).unwrap() == read_image(&jpg, 3).unwrap());
        let cut = &full[..full.len() * 2 / 3];
        assert!(jpeg_complete(&full) && !jpeg_complete(cut));
        let t = dir.path().join("cut.jpg");
        std::fs::write(&t, cut).unwrap();
        match read_image(&t, 3) {
            Ok(_) => panic!("a cut JPEG was read"),
            Err(e) => assert!(e.to_string().contains("cut.jpg"), "{e}"),
        }
        // PNG chunks walked by their lengths: a file ending inside a chunk whose data holds the
        // word IEND is refused.
        let bytes = std::fs::read(&png).unwrap();
        let mut fake = bytes[..bytes.len() - 12].to_vec(); // without its IEND chunk
        fake.extend(40u32.to_be_bytes());
        fake.extend(b"tEXt");
        fake.extend(b"note\0IEND\0\0\0\0\xAEB`\x82");
        assert!(png_complete(&bytes) && !png_complete(&fake));
        let t = dir.path().join("fake.png");
        std::fs::write(&t, &fake).unwrap();
        let e = read_image(&t, 3).unwrap_err().to_string();
        assert!(e.contains("truncated PNG"), "{e}");
    }

    /// A view's photo with transparent pixels reads composited onto white; an opaque RGBA photo
    /// reads as its RGB.
    #[test]
    fn photos_with_transparent_pixels_are_composited_onto_white() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = ImageF32::new(8, 6, 4);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = if i % 4 == 3 {
                1.0
            } else {
                (i % 13) as f32 / 13.0
            };
        }
        let opaque = dir.path().join("opaque.png");
        write_png(&opaque, &img).unwrap();
        let rgb = read_photo(&opaque).unwrap();
        assert!(rgb == read_image(&opaque, 3).unwrap());
        assert_eq!(rgb.channels, 3);
        // Pixel 5 transparent, pixel 9 half (alpha 128/255 in the file).
        img.data[4 * 5 + 3] = 0.0;
        img.data[4 * 9 + 3] = 128.0 / 255.0;
        let holes = dir.path().join("holes.png");
        write_png(&holes, &img).unwrap();
        let back = read_photo(&holes).unwrap();
        let stored = read_image(&holes, 4).unwrap();
        for p in 0..48 {
            let a = stored.data[4 * p + 3];
            for c in 0..3 {
                let want = stored.data[4 * p + c] * a + 1.0 - a;
                assert!((back.data[3 * p + c] - want).abs() < 1e-6, "pixel {p}");
            }
        }
        assert_eq!(&back.data[15..18], &[1.0, 1.0, 1.0]);
    }

    /// deepview's PNGs and JPEGs carry its mark and read back as before; a photo from elsewhere, a
    /// GIF without the comment before its trailer and an unmarked MP4 do not.
    #[test]
    fn outputs_carry_the_mark_and_photos_do_not() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = ImageF32::new(9, 7, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = (i % 17) as f32 / 17.0;
        }
        let png = dir.path().join("a.png");
        write_png(&png, &img).unwrap();
        assert!(written_by_deepview(&png));
        assert!(
            read_image(&png, 3).unwrap()
                == ImageF32::from_data(
                    9,
                    7,
                    3,
                    img.to_u8().iter().map(|&b| b as f32 / 255.0).collect()
                )
                .unwrap()
        );
        let jpg = dir.path().join("a.jpg");
        super::write_jpeg(&jpg, &img, 90).unwrap();
        assert!(written_by_deepview(&jpg));
        // The JFIF header stays the first segment.
        let bytes = std::fs::read(&jpg).unwrap();
        assert_eq!(&bytes[2..4], &[0xFF, 0xE0]);
        assert_eq!(&bytes[6..11], b"JFIF\0");
        assert_eq!(
            (
                read_image(&jpg, 3).unwrap().width,
                read_image(&jpg, 3).unwrap().height
            ),
            (9, 7)
        );
        let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
        if data.is_dir() {
            for photo in [
                "llff/fern/images_8/image000.png",
                "colmap/room/images/img001.JPG",
            ] {
                assert!(!written_by_deepview(&data.join(photo)), "{photo}");
            }
            // A copy given the mark (export-web's layers of another program's MPI) has it once and
            // decodes to the same pixels; a marked file is left as it is, a JPEG too.
            let fern = data.join("llff/fern/images_8/image000.png");
            let copy = dir.path().join("copy.png");
            let bytes = with_mark(std::fs::read(&fern).unwrap());
            assert_eq!(with_mark(bytes.clone()), bytes);
            std::fs::write(&copy, &bytes).unwrap();
            assert!(written_by_deepview(&copy));
            assert_eq!(read_image(&copy, 3).unwrap(), read_image(&fern, 3).unwrap());
            let room = std::fs::read(data.join("colmap/room/images/img001.JPG")).unwrap();
            assert_eq!(with_mark(room.clone()), room);
        }
        let gif = dir.path().join("a.gif");
        let mut bytes = b"GIF89a\x01\0\x01\0\0\0\0".to_vec();
        std::fs::write(&gif, [&bytes[..], &[0x3B]].concat()).unwrap();
        assert!(!written_by_deepview(&gif));
        bytes.extend_from_slice(&GIF_MARK);
        bytes.push(0x3B);
        std::fs::write(&gif, &bytes).unwrap();
        assert!(written_by_deepview(&gif));
        let mp4 = dir.path().join("a.mp4");
        std::fs::write(&mp4, b"\0\0\0\x18ftypisom\0\0\x02\0isomiso2").unwrap();
        assert!(!written_by_deepview(&mp4));
        std::fs::write(
            &mp4,
            b"\0\0\0\x18ftypisom\0\0\x02\0isomiso2....\xa9cmtdeepview",
        )
        .unwrap();
        assert!(written_by_deepview(&mp4));
        // The PNG mark's chunk is well formed: its CRC is PNG's.
        assert_eq!(crc32(b"IEND"), 0xAE42_6082);
    }

    /// A file of a format deepview does not read, named as a PNG: the error says what it is.
    #[test]
    fn other_formats_named_png_say_what_they_are() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("view.png");
        let mut tiff = b"II*\0\x08\0\0\0".to_vec();
        tiff.extend([0u8; 64]);
        let mut heic = b"\0\0\0\x18ftypheic\0\0\0\0mif1heic".to_vec();
        heic.extend([0u8; 64]);
        for (bytes, what) in [
            (tiff, "is a TIFF file"),
            (b"P6\n4 4\n255\n".to_vec(), "is a PNM file"),
            (heic, "is a HEIC/HEIF file"),
        ] {
            std::fs::write(&p, &bytes).unwrap();
            let e = read_image(&p, 3).unwrap_err().to_string();
            assert!(e.contains("view.png") && e.contains(what), "{e}");
        }
    }

    #[test]
    fn downscale_and_crop() {
        let mut img = ImageF32::new(4, 2, 1);
        img.data = vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        assert_eq!(img.downscale(2).data, vec![2.5, 4.5]);
        assert_eq!(img.crop(1, 1, 2, 1).data, vec![5.0, 6.0]);
    }
}
