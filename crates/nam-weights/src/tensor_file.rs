//! A small, defensive safetensors reader (and F32 writer).
//!
//! The reader checks every size against the length of the buffer *before*
//! allocating, uses checked arithmetic throughout, and never panics on any
//! input: a header that claims a terabyte tensor in a kilobyte file is an error,
//! not an allocation.

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::Value;

use crate::error::{Result, WeightsError};

/// Largest JSON header accepted, in bytes (the reference implementation's limit).
pub const MAX_HEADER_BYTES: usize = 100_000_000;

/// Storage dtypes this reader converts to `f32`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    /// IEEE binary32.
    F32,
    /// IEEE binary16.
    F16,
    /// bfloat16.
    BF16,
    /// IEEE binary64 (narrowed to f32; used by golden fixtures).
    F64,
}

impl Dtype {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "F32" => Some(Self::F32),
            "F16" => Some(Self::F16),
            "BF16" => Some(Self::BF16),
            "F64" => Some(Self::F64),
            _ => None,
        }
    }

    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Self::F16 | Self::BF16 => 2,
            Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

/// A dense row-major `f32` tensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    shape: Vec<usize>,
    data: Vec<f32>,
}

impl Tensor {
    /// Builds a tensor; `None` when `data.len()` is not the product of `shape`.
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Option<Self> {
        let n = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))?;
        (n == data.len()).then_some(Self { shape, data })
    }

    /// Dimensions, outermost first.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Row-major elements.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Consumes the tensor, returning its elements.
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }
}

/// All tensors of one safetensors file, converted to `f32`, plus its string metadata.
#[derive(Debug, Clone)]
pub struct TensorFile {
    label: String,
    metadata: BTreeMap<String, String>,
    tensors: BTreeMap<String, Tensor>,
    dtypes: BTreeMap<String, Dtype>,
}

struct Entry {
    name: String,
    dtype: Dtype,
    shape: Vec<usize>,
    start: usize,
    end: usize,
}

impl TensorFile {
    /// Reads and parses a file. The label used in errors is the path.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| WeightsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses an in-memory file (e.g. from `include_bytes!`); `label` names it in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self> {
        let fmt = |reason: String| WeightsError::Format {
            file: label.to_string(),
            reason,
        };
        let len_bytes: [u8; 8] =
            bytes
                .get(..8)
                .and_then(|s| s.try_into().ok())
                .ok_or_else(|| {
                    fmt(format!(
                        "{} bytes is shorter than the 8-byte length prefix",
                        bytes.len()
                    ))
                })?;
        let header_len = u64::from_le_bytes(len_bytes);
        let available = bytes.len() - 8;
        let header_len = usize::try_from(header_len)
            .ok()
            .filter(|&n| n <= MAX_HEADER_BYTES && n <= available)
            .ok_or_else(|| {
                fmt(format!(
                    "header length {header_len} exceeds the {available} bytes after the prefix (or the {MAX_HEADER_BYTES}-byte limit)"
                ))
            })?;
        let header = &bytes[8..8 + header_len];
        let data = &bytes[8 + header_len..];
        let root: serde_json::Map<String, Value> = serde_json::from_slice(header)
            .map_err(|e| fmt(format!("header is not a JSON object: {e}")))?;

        let mut metadata = BTreeMap::new();
        let mut entries = Vec::with_capacity(root.len());
        for (name, value) in &root {
            if name == "__metadata__" {
                let obj = value
                    .as_object()
                    .ok_or_else(|| fmt("__metadata__ is not an object".into()))?;
                for (k, v) in obj {
                    let v = v
                        .as_str()
                        .ok_or_else(|| fmt(format!("__metadata__[{k:?}] is not a string")))?;
                    metadata.insert(k.clone(), v.to_string());
                }
                continue;
            }
            entries.push(parse_entry(name, value, label)?);
        }

        // The byte buffer must be covered exactly, without holes or overlaps.
        entries.sort_by_key(|e| (e.start, e.end));
        let mut cursor = 0usize;
        for e in &entries {
            if e.start != cursor {
                return Err(fmt(format!(
                    "tensor `{}` starts at byte {} but the previous tensor ends at {cursor}",
                    e.name, e.start
                )));
            }
            if e.end > data.len() {
                return Err(fmt(format!(
                    "tensor `{}` ends at byte {} but the data section has only {} bytes",
                    e.name,
                    e.end,
                    data.len()
                )));
            }
            cursor = e.end;
        }
        if cursor != data.len() {
            return Err(fmt(format!(
                "tensors cover {cursor} bytes but the data section has {} bytes",
                data.len()
            )));
        }

        // All sizes are now bounded by the buffer length: allocation is safe.
        let mut tensors = BTreeMap::new();
        let mut dtypes = BTreeMap::new();
        for e in entries {
            let raw = &data[e.start..e.end];
            let values = convert(raw, e.dtype);
            dtypes.insert(e.name.clone(), e.dtype);
            tensors.insert(
                e.name,
                Tensor {
                    shape: e.shape,
                    data: values,
                },
            );
        }
        Ok(Self {
            label: label.to_string(),
            metadata,
            tensors,
            dtypes,
        })
    }

    /// The label (path or caller-given name) used in errors.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// `__metadata__` key/value strings.
    pub fn metadata(&self) -> &BTreeMap<String, String> {
        &self.metadata
    }

    /// All tensors by name.
    pub fn tensors(&self) -> &BTreeMap<String, Tensor> {
        &self.tensors
    }

    /// Storage dtype of a tensor as found in the file.
    pub fn dtype(&self, name: &str) -> Option<Dtype> {
        self.dtypes.get(name).copied()
    }

    /// Returns the data of `name`, checking that its shape is exactly `shape`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<&[f32]> {
        get_checked(&self.tensors, &self.label, name, shape)
    }

    /// Splits into metadata and tensors.
    pub fn into_parts(self) -> (BTreeMap<String, String>, BTreeMap<String, Tensor>) {
        (self.metadata, self.tensors)
    }
}

/// The data of `name` in `tensors`, checking that its shape is exactly `shape`; `label` names
/// the file in errors.
pub(crate) fn get_checked<'a>(
    tensors: &'a BTreeMap<String, Tensor>,
    label: &str,
    name: &str,
    shape: &[usize],
) -> Result<&'a [f32]> {
    let t = tensors
        .get(name)
        .ok_or_else(|| WeightsError::MissingTensor {
            file: label.to_string(),
            tensor: name.to_string(),
            expected: shape.to_vec(),
        })?;
    if t.shape != shape {
        return Err(WeightsError::ShapeMismatch {
            file: label.to_string(),
            tensor: name.to_string(),
            expected: shape.to_vec(),
            found: t.shape.clone(),
        });
    }
    Ok(&t.data)
}

fn parse_entry(name: &str, value: &Value, label: &str) -> Result<Entry> {
    let fmt = |reason: String| WeightsError::Format {
        file: label.to_string(),
        reason: format!("tensor `{name}`: {reason}"),
    };
    let obj = value
        .as_object()
        .ok_or_else(|| fmt("header entry is not an object".into()))?;
    let dtype_str = obj
        .get("dtype")
        .and_then(Value::as_str)
        .ok_or_else(|| fmt("missing string `dtype`".into()))?;
    let dtype = Dtype::parse(dtype_str).ok_or_else(|| WeightsError::UnsupportedDtype {
        file: label.to_string(),
        tensor: name.to_string(),
        dtype: dtype_str.to_string(),
    })?;
    let shape = obj
        .get("shape")
        .and_then(Value::as_array)
        .ok_or_else(|| fmt("missing array `shape`".into()))?
        .iter()
        .map(|d| d.as_u64().and_then(|d| usize::try_from(d).ok()))
        .collect::<Option<Vec<usize>>>()
        .ok_or_else(|| fmt("`shape` holds a non-integer or out-of-range dimension".into()))?;
    let offsets = obj
        .get("data_offsets")
        .and_then(Value::as_array)
        .filter(|a| a.len() == 2)
        .ok_or_else(|| fmt("missing 2-element `data_offsets`".into()))?;
    let off = |i: usize| {
        offsets[i]
            .as_u64()
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| fmt("`data_offsets` holds a non-integer or out-of-range value".into()))
    };
    let (start, end) = (off(0)?, off(1)?);
    let nbytes = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .and_then(|n| n.checked_mul(dtype.size()))
        .ok_or_else(|| fmt(format!("shape {shape:?} overflows the address space")))?;
    if end < start || end - start != nbytes {
        return Err(fmt(format!(
            "data_offsets [{start}, {end}] do not span the {nbytes} bytes of shape {shape:?} {dtype_str}"
        )));
    }
    Ok(Entry {
        name: name.to_string(),
        dtype,
        shape,
        start,
        end,
    })
}

fn convert(raw: &[u8], dtype: Dtype) -> Vec<f32> {
    match dtype {
        Dtype::F32 => raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        Dtype::F16 => raw
            .chunks_exact(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        Dtype::BF16 => raw
            .chunks_exact(2)
            .map(|c| half::bf16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        Dtype::F64 => raw
            .chunks_exact(8)
            .map(|c| {
                let mut b = [0u8; 8];
                b.copy_from_slice(c);
                f64::from_le_bytes(b) as f32
            })
            .collect(),
    }
}

/// Serialises tensors as an F32 safetensors file with the given `__metadata__`.
///
/// Tensors are laid out in name order; the header is padded with spaces to a
/// multiple of 8 bytes as the reference implementation does.
pub fn write_safetensors(
    tensors: &BTreeMap<String, Tensor>,
    metadata: &BTreeMap<String, String>,
) -> Vec<u8> {
    let mut header = serde_json::Map::new();
    if !metadata.is_empty() {
        let m = metadata
            .iter()
            .map(|(k, v)| (k.clone(), Value::String(v.clone())))
            .collect();
        header.insert("__metadata__".into(), Value::Object(m));
    }
    let mut offset = 0usize;
    for (name, t) in tensors {
        let n = t.data.len() * 4;
        header.insert(
            name.clone(),
            serde_json::json!({"dtype": "F32", "shape": t.shape, "data_offsets": [offset, offset + n]}),
        );
        offset += n;
    }
    let mut header = Value::Object(header).to_string().into_bytes();
    while !header.len().is_multiple_of(8) {
        header.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + header.len() + offset);
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(&header);
    for t in tensors.values() {
        for v in &t.data {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}
