//! A small `.npy` reader and writer for float arrays (format versions 1, 2 and 3; `<f8`, `<f4`, `>f8`,
//! `>f4`; C or Fortran order). Data is returned in C (row-major) order as `f64`.

use crate::DataError;
use std::path::Path;

const MAGIC: &[u8] = b"\x93NUMPY";

/// A float array in C order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

/// Read a `.npy` file.
pub fn read_npy(path: &Path) -> Result<NpyArray, DataError> {
    parse_npy(&crate::read_file(path)?, path)
}

/// Parse `.npy` bytes; `path` only names the source in errors.
pub fn parse_npy(bytes: &[u8], path: &Path) -> Result<NpyArray, DataError> {
    let err = |msg: String| DataError::Invalid {
        path: path.into(),
        msg: format!("malformed .npy file: {msg}"),
    };
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(err(
            "missing the \\x93NUMPY magic string (not a .npy file or truncated)".into(),
        ));
    }
    let major = bytes[6];
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(err("truncated header".into()));
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(err(format!("unsupported format version {v}"))),
    };
    let end = start + header_len;
    if bytes.len() < end {
        return Err(err(format!(
            "header says {header_len} bytes but the file ends at {}",
            bytes.len()
        )));
    }
    let header =
        std::str::from_utf8(&bytes[start..end]).map_err(|_| err("header is not text".into()))?;
    let descr = dict_value(header, "descr")
        .ok_or_else(|| err(format!("no 'descr' in header {header:?}")))?;
    let descr = descr.trim().trim_matches(|c| c == '\'' || c == '"');
    let fortran = dict_value(header, "fortran_order")
        .ok_or_else(|| err(format!("no 'fortran_order' in header {header:?}")))?;
    let fortran = match fortran.trim() {
        "True" => true,
        "False" => false,
        v => {
            return Err(err(format!(
                "fortran_order must be True or False, got {v:?}"
            )));
        }
    };
    let shape = dict_value(header, "shape")
        .ok_or_else(|| err(format!("no 'shape' in header {header:?}")))?;
    let shape = parse_shape(shape).ok_or_else(|| err(format!("cannot parse shape {shape:?}")))?;
    let (size, little) = match descr {
        "<f8" | "=f8" => (8, true),
        "<f4" | "=f4" => (4, true),
        ">f8" => (8, false),
        ">f4" => (4, false),
        d => {
            return Err(err(format!(
                "unsupported dtype {d:?} (expected float64 or float32)"
            )));
        }
    };
    // Checked to the byte count: a count times the item size that wraps must not pass as a few bytes.
    let data_bytes = shape
        .iter()
        .try_fold(size, |a: usize, &b| a.checked_mul(b))
        .ok_or_else(|| err(format!("shape {shape:?} overflows")))?;
    let payload = &bytes[end..];
    if payload.len() < data_bytes {
        return Err(err(format!(
            "truncated: shape {shape:?} needs {data_bytes} data bytes, the file has {}",
            payload.len()
        )));
    }
    let data: Vec<f64> = payload[..data_bytes]
        .chunks_exact(size)
        .map(|c| match (size, little) {
            (8, true) => f64::from_le_bytes(c.try_into().unwrap()),
            (8, false) => f64::from_be_bytes(c.try_into().unwrap()),
            (_, true) => f32::from_le_bytes(c.try_into().unwrap()) as f64,
            (_, false) => f32::from_be_bytes(c.try_into().unwrap()) as f64,
        })
        .collect();
    let data = if fortran && shape.len() > 1 {
        fortran_to_c(&data, &shape)
    } else {
        data
    };
    Ok(NpyArray { shape, data })
}

/// The text of a value in a Python dict literal (`'key': value,`), up to the next top-level comma or `}`.
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pos = header
        .find(&format!("'{key}'"))
        .or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = &header[pos + key.len() + 2..];
    let rest = rest.trim_start().strip_prefix(':')?;
    let mut depth = 0i32;
    for (i, ch) in rest.char_indices() {
        match ch {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(&rest[..i]),
            _ => {}
        }
    }
    None
}

fn parse_shape(s: &str) -> Option<Vec<usize>> {
    let inner = s.trim().strip_prefix('(')?.strip_suffix(')')?;
    inner
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| t.trim_end_matches('L').parse().ok())
        .collect()
}

fn fortran_to_c(data: &[f64], shape: &[usize]) -> Vec<f64> {
    let n = shape.len();
    let mut out = vec![0.0; data.len()];
    let mut idx = vec![0usize; n];
    // Fortran strides: first axis fastest.
    let mut fstride = vec![1usize; n];
    for k in 1..n {
        fstride[k] = fstride[k - 1] * shape[k - 1];
    }
    for o in out.iter_mut() {
        *o = data[idx.iter().zip(&fstride).map(|(i, s)| i * s).sum::<usize>()];
        for k in (0..n).rev() {
            idx[k] += 1;
            if idx[k] < shape[k] {
                break;
            }
            idx[k] = 0;
        }
    }
    out
}

/// `.npy` bytes (version 1, `<f8`, C order) for `data` of `shape`.
pub fn npy_bytes(shape: &[usize], data: &[f64]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "npy_bytes: shape does not match the data"
    );
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_txt = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape_txt}, }}");
    let total = MAGIC.len() + 4 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 8);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Write a `<f8` C-order `.npy` file atomically.
pub fn write_npy(path: &Path, shape: &[usize], data: &[f64]) -> Result<(), DataError> {
    if shape.iter().product::<usize>() != data.len() {
        return Err(DataError::invalid(
            path,
            format!("shape {shape:?} does not match {} values", data.len()),
        ));
    }
    crate::write_bytes(path, &npy_bytes(shape, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("mem.npy")
    }

    fn with_header(version: u8, header: &str, payload: &[u8]) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&[version, 0]);
        if version == 1 {
            out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        } else {
            out.extend_from_slice(&(header.len() as u32).to_le_bytes());
        }
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(payload);
        out
    }

    #[test]
    fn round_trip_and_alignment() {
        let data: Vec<f64> = (0..6).map(|i| i as f64 * 0.5 - 1.0).collect();
        let b = npy_bytes(&[2, 3], &data);
        let header_end = 10 + u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!(header_end % 64, 0);
        assert_eq!(
            parse_npy(&b, p()).unwrap(),
            NpyArray {
                shape: vec![2, 3],
                data
            }
        );
        let one = npy_bytes(&[3], &[1.0, 2.0, 3.0]);
        assert_eq!(parse_npy(&one, p()).unwrap().shape, vec![3]);
    }

    #[test]
    fn v2_f4_and_fortran_order() {
        // Column-major [[1, 2, 3], [4, 5, 6]] stored as 1 4 2 5 3 6, float32.
        let payload: Vec<u8> = [1.0f32, 4.0, 2.0, 5.0, 3.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let b = with_header(
            2,
            "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }\n",
            &payload,
        );
        let a = parse_npy(&b, p()).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.data, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let payload: Vec<u8> = [1.5f64, -2.0]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let b = with_header(
            1,
            "{'descr': '>f8', 'fortran_order': False, 'shape': (2,), }\n",
            &payload,
        );
        assert_eq!(parse_npy(&b, p()).unwrap().data, vec![1.5, -2.0]);
    }

    #[test]
    fn malformed_files_are_refused_with_the_file_name() {
        let good = npy_bytes(&[2, 17], &[0.0; 34]);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (good[..good.len() - 8].to_vec(), "truncated"),
            (good[..5].to_vec(), "magic"),
            (b"PK\x03\x04 not npy at all".to_vec(), "magic"),
            (good[..40].to_vec(), "header says"),
            (
                with_header(
                    1,
                    "{'descr': '<i8', 'fortran_order': False, 'shape': (2,), }\n",
                    &[0; 16],
                ),
                "dtype",
            ),
            (
                with_header(1, "{'descr': '<f8', 'shape': (2,), }\n", &[0; 16]),
                "fortran_order",
            ),
            (
                with_header(
                    1,
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (2,x), }\n",
                    &[0; 16],
                ),
                "shape",
            ),
            (with_header(7, "{}", &[]), "version"),
            // 2^61 float64s are 2^64 bytes: the byte count wraps to 0 (found by tests/fuzz.rs).
            (
                with_header(
                    1,
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (2305843009213693952,), }\n",
                    &[],
                ),
                "overflows",
            ),
        ];
        for (bytes, want) in cases {
            let e = parse_npy(&bytes, p()).unwrap_err().to_string();
            assert!(e.contains("mem.npy") && e.contains(want), "{want}: {e}");
        }
    }
}
