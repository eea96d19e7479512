//! The "tensor_file" container of RGL `.bsdf` files: magic "tensor_file\0", version 1.0, u32 field
//! count, then per field u16 name length, name, u16 ndim, u8 dtype, u64 offset, ndim x u64 shape;
//! data blocks at absolute offsets, little-endian, C order.

use crate::brdf::BrdfError;
use std::collections::HashMap;
use std::path::Path;

pub const MAGIC: &[u8; 12] = b"tensor_file\0";
pub const DTYPE_U8: u8 = 1;
pub const DTYPE_U32: u8 = 5;
pub const DTYPE_F32: u8 = 10;

/// Bytes per element of each dtype code (1 u8 ... 11 f64).
fn dtype_size(dtype: u8) -> Option<usize> {
    match dtype {
        1 | 2 => Some(1),
        3 | 4 | 9 => Some(2),
        5 | 6 | 10 => Some(4),
        7 | 8 | 11 => Some(8),
        _ => None,
    }
}

#[derive(Clone, Debug)]
pub struct Field {
    pub dtype: u8,
    pub shape: Vec<usize>,
    /// The raw little-endian data block.
    pub bytes: Vec<u8>,
}

impl Field {
    pub fn as_f32(&self) -> Vec<f32> {
        self.bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    }
}

/// A little-endian cursor that reports truncation as a format error.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], BrdfError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| BrdfError::format(self.path, "RGL tensor file: header is truncated"))?;
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16, BrdfError> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u64(&mut self) -> Result<u64, BrdfError> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
}

/// Parse every field of a tensor file.
pub fn parse(bytes: &[u8], path: &Path) -> Result<HashMap<String, Field>, BrdfError> {
    let bad = |reason: String| BrdfError::format(path, format!("RGL tensor file: {reason}"));
    if bytes.len() < 18 || &bytes[..12] != MAGIC {
        return Err(bad("bad magic (expected \"tensor_file\\0\")".into()));
    }
    if (bytes[12], bytes[13]) != (1, 0) {
        return Err(bad(format!("version {}.{}, expected 1.0", bytes[12], bytes[13])));
    }
    let count = u32::from_le_bytes([bytes[14], bytes[15], bytes[16], bytes[17]]) as usize;
    let mut cur = Cursor { bytes, pos: 18, path };
    let mut fields = HashMap::new();
    for _ in 0..count {
        let name_len = cur.u16()? as usize;
        let name =
            String::from_utf8(cur.take(name_len)?.to_vec()).map_err(|_| bad("a field name is not UTF-8".into()))?;
        let ndim = cur.u16()? as usize;
        let dtype = cur.take(1)?[0];
        let offset = cur.u64()?;
        let mut shape = Vec::with_capacity(ndim);
        for _ in 0..ndim {
            shape.push(usize::try_from(cur.u64()?).map_err(|_| bad(format!("field '{name}': shape too large")))?);
        }
        let size = dtype_size(dtype).ok_or_else(|| bad(format!("field '{name}': unknown dtype {dtype}")))?;
        let len = shape
            .iter()
            .try_fold(size, |acc, &d| acc.checked_mul(d))
            .ok_or_else(|| bad(format!("field '{name}': shape overflows")))?;
        let start = usize::try_from(offset).map_err(|_| bad(format!("field '{name}': offset too large")))?;
        let end = start.checked_add(len).filter(|&e| e <= bytes.len());
        let end = end.ok_or_else(|| bad(format!("field '{name}': data block past the end of the file")))?;
        fields.insert(
            name,
            Field {
                dtype,
                shape,
                bytes: bytes[start..end].to_vec(),
            },
        );
    }
    Ok(fields)
}

/// Serialise fields (in the given order) with every data block 8-byte aligned, as RGL's and
/// Mitsuba's writers do.
pub fn write(fields: &[(&str, u8, Vec<usize>, Vec<u8>)]) -> Vec<u8> {
    let header_len: usize = 18
        + fields
            .iter()
            .map(|(n, _, s, _)| 2 + n.len() + 2 + 1 + 8 + 8 * s.len())
            .sum::<usize>();
    let align = |x: usize| x.div_ceil(8) * 8;
    let mut offset = align(header_len);
    let mut header = Vec::with_capacity(header_len);
    header.extend_from_slice(MAGIC);
    header.extend_from_slice(&[1, 0]);
    header.extend_from_slice(&(fields.len() as u32).to_le_bytes());
    let mut offsets = Vec::new();
    for (name, dtype, shape, data) in fields {
        header.extend_from_slice(&(name.len() as u16).to_le_bytes());
        header.extend_from_slice(name.as_bytes());
        header.extend_from_slice(&(shape.len() as u16).to_le_bytes());
        header.push(*dtype);
        header.extend_from_slice(&(offset as u64).to_le_bytes());
        for d in shape {
            header.extend_from_slice(&(*d as u64).to_le_bytes());
        }
        offsets.push(offset);
        offset = align(offset + data.len());
    }
    let mut out = header;
    for ((_, _, _, data), off) in fields.iter().zip(offsets) {
        out.resize(off, 0);
        out.extend_from_slice(data);
    }
    out
}
