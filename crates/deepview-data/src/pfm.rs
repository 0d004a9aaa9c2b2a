//! Portable float maps (`.pfm`): `Pf` (1 channel) or `PF` (3 channels), `width height`, a scale whose sign
//! gives the byte order (negative: little-endian), then rows stored bottom to top. Returned top to bottom.

use crate::DataError;
use std::path::Path;

/// A float map, rows top to bottom, channels interleaved.
#[derive(Clone, Debug, PartialEq)]
pub struct Pfm {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

pub fn read_pfm(path: &Path) -> Result<Pfm, DataError> {
    parse_pfm(&crate::read_file(path)?, path)
}

/// Parse PFM bytes; `path` only names the source in errors.
pub fn parse_pfm(bytes: &[u8], path: &Path) -> Result<Pfm, DataError> {
    let err = |msg: String| DataError::Invalid {
        path: path.into(),
        msg: format!("malformed PFM file: {msg}"),
    };
    // Three whitespace-separated header tokens after the magic: width, height, scale; one whitespace byte
    // then the data.
    let mut tokens = Vec::new();
    let mut i = 0;
    while tokens.len() < 4 {
        while i < bytes.len() && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        let s = i;
        while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if s == i || i >= bytes.len() {
            return Err(err("truncated header".into()));
        }
        tokens.push(String::from_utf8_lossy(&bytes[s..i]).into_owned());
    }
    i += 1; // the single whitespace byte ending the header
    let channels = match tokens[0].as_str() {
        "Pf" => 1,
        "PF" => 3,
        m => return Err(err(format!("bad magic {m:?} (expected Pf or PF)"))),
    };
    let width: usize = tokens[1]
        .parse()
        .map_err(|_| err(format!("bad width {:?}", tokens[1])))?;
    let height: usize = tokens[2]
        .parse()
        .map_err(|_| err(format!("bad height {:?}", tokens[2])))?;
    let scale: f64 = tokens[3]
        .parse()
        .map_err(|_| err(format!("bad scale {:?}", tokens[3])))?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(err(format!("bad scale {scale}")));
    }
    let little = scale < 0.0;
    // Checked to the byte count: a size whose product wraps must not pass as a few bytes.
    let (row, n) = width
        .checked_mul(channels)
        .and_then(|row| Some((row, row.checked_mul(height)?)))
        .filter(|(_, n)| n.checked_mul(4).is_some())
        .ok_or_else(|| err(format!("size {width}x{height}x{channels} overflows")))?;
    let payload = bytes.get(i..).unwrap_or(&[]);
    if payload.len() < n * 4 {
        return Err(err(format!(
            "truncated: {width}x{height}x{channels} needs {} bytes, has {}",
            n * 4,
            payload.len()
        )));
    }
    let mut data = vec![0.0f32; n];
    for (k, c) in payload[..n * 4].chunks_exact(4).enumerate() {
        let v = if little {
            f32::from_le_bytes(c.try_into().unwrap())
        } else {
            f32::from_be_bytes(c.try_into().unwrap())
        };
        let (y_file, x) = (k / row, k % row);
        data[(height - 1 - y_file) * row + x] = v;
    }
    Ok(Pfm {
        width,
        height,
        channels,
        data,
    })
}

/// PFM bytes (little-endian) of `pfm` (rows top to bottom in memory).
pub fn pfm_bytes(pfm: &Pfm) -> Vec<u8> {
    let magic = if pfm.channels == 3 { "PF" } else { "Pf" };
    let mut out = format!("{magic}\n{} {}\n-1\n", pfm.width, pfm.height).into_bytes();
    let row = pfm.width * pfm.channels;
    for y in (0..pfm.height).rev() {
        for v in &pfm.data[y * row..(y + 1) * row] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

pub fn write_pfm(path: &Path, pfm: &Pfm) -> Result<(), DataError> {
    if !matches!(pfm.channels, 1 | 3) || pfm.data.len() != pfm.width * pfm.height * pfm.channels {
        return Err(DataError::invalid(
            path,
            "PFM needs 1 or 3 channels and matching data length",
        ));
    }
    crate::write_bytes(path, &pfm_bytes(pfm))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_row_order() {
        let pfm = Pfm {
            width: 3,
            height: 2,
            channels: 1,
            data: vec![1.0, 2.0, 3.0, 4.0, 5.0, -6.5],
        };
        let b = pfm_bytes(&pfm);
        // The first stored row is the bottom one.
        let hdr = b"Pf\n3 2\n-1\n".len();
        assert_eq!(f32::from_le_bytes(b[hdr..hdr + 4].try_into().unwrap()), 4.0);
        assert_eq!(parse_pfm(&b, Path::new("m.pfm")).unwrap(), pfm);
        // Big-endian, scale > 0.
        let mut be = b"Pf\n1 1\n1.0\n".to_vec();
        be.extend_from_slice(&2.5f32.to_be_bytes());
        assert_eq!(parse_pfm(&be, Path::new("m.pfm")).unwrap().data, vec![2.5]);
    }

    #[test]
    fn malformed() {
        for (b, want) in [
            (&b"P6\n1 1\n-1\n\0\0\0\0"[..], "magic"),
            (&b"Pf\n2 2\n-1\n\0\0\0\0"[..], "truncated"),
            (&b"Pf\n2"[..], "truncated header"),
            (&b"Pf\nx 2\n-1\n\0\0\0\0"[..], "width"),
            // 2^63 x 4 wraps to 0 values (found by tests/fuzz.rs).
            (&b"Pf\n9223372036854775808 4\n-1\n"[..], "overflows"),
        ] {
            let e = parse_pfm(b, Path::new("m.pfm")).unwrap_err().to_string();
            assert!(e.contains("m.pfm") && e.contains(want), "{e}");
        }
    }
}
