//! safetensors files as `f32` tensors, read and written through the `safetensors` crate.
//!
//! The crate checks the container before anything is sliced or allocated from a size in the
//! file: the length prefix, the 100 MB header limit, the JSON header, shape × dtype sizes with
//! overflow checks, and offsets that tile the data section exactly (no gap, overlap or trailing
//! byte). This module adds what nam needs on top: conversion of the float dtypes to `f32`, and
//! errors that name the file and, where the crate's error does not, the tensor.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use safetensors::tensor::TensorInfo;
use safetensors::{SafeTensorError, SafeTensors, View};

use crate::error::{Result, WeightsError};

/// Largest JSON header accepted, in bytes (the `safetensors` crate's limit).
pub const MAX_HEADER_BYTES: usize = 100_000_000;

/// Bytes of the little-endian `u64` header-length prefix.
const PREFIX_BYTES: usize = 8;

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
    fn from_safetensors(d: safetensors::Dtype) -> Option<Self> {
        match d {
            safetensors::Dtype::F32 => Some(Self::F32),
            safetensors::Dtype::F16 => Some(Self::F16),
            safetensors::Dtype::BF16 => Some(Self::BF16),
            safetensors::Dtype::F64 => Some(Self::F64),
            _ => None,
        }
    }

    /// Little-endian bytes (length checked by the crate) as `f32`.
    fn to_f32(self, raw: &[u8]) -> Vec<f32> {
        match self {
            Self::F32 => raw
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            Self::F16 => raw
                .chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect(),
            Self::BF16 => raw
                .chunks_exact(2)
                .map(|c| half::bf16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect(),
            Self::F64 => raw
                .chunks_exact(8)
                .map(|c| {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(c);
                    f64::from_le_bytes(b) as f32
                })
                .collect(),
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
}

/// A borrowed row-major `f32` tensor: what the writers serialise, without copying the values.
#[derive(Debug, Clone, Copy)]
pub struct TensorView<'a> {
    shape: &'a [usize],
    data: &'a [f32],
}

impl<'a> TensorView<'a> {
    /// Borrows `data` as a tensor of `shape`; `None` when `data.len()` is not its product.
    pub fn new(shape: &'a [usize], data: &'a [f32]) -> Option<Self> {
        let n = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))?;
        (n == data.len()).then_some(Self { shape, data })
    }
}

impl Tensor {
    /// This tensor, borrowed.
    pub fn view(&self) -> TensorView<'_> {
        TensorView {
            shape: &self.shape,
            data: &self.data,
        }
    }
}

/// A tensor as the `safetensors` crate writes it: F32, or F16 (rounded to nearest; the caller
/// checks the range), little-endian.
struct StoredView<'a>(TensorView<'a>, StoreAs);

impl View for StoredView<'_> {
    fn dtype(&self) -> safetensors::Dtype {
        self.1.dtype()
    }

    fn shape(&self) -> &[usize] {
        self.0.shape
    }

    fn data(&self) -> Cow<'_, [u8]> {
        let mut bytes = Vec::with_capacity(self.data_len());
        self.1.encode(self.0.data, &mut bytes);
        Cow::Owned(bytes)
    }

    fn data_len(&self) -> usize {
        self.0.data.len() * self.1.bytes()
    }
}

/// The dtype [`write_safetensors_as`] stores tensors in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreAs {
    /// IEEE binary32: exact.
    F32,
    /// IEEE binary16: half the bytes; values rounded to 11 significant bits, and beyond
    /// ±65504 they would become ±Inf, so callers store F16 only what fits.
    F16,
}

impl StoreAs {
    /// Bytes per value.
    pub fn bytes(self) -> usize {
        match self {
            StoreAs::F32 => 4,
            StoreAs::F16 => 2,
        }
    }

    /// Appends `values` as little-endian bytes of this dtype (F16 rounded to nearest).
    fn encode(self, values: &[f32], out: &mut Vec<u8>) {
        match self {
            StoreAs::F32 => out.extend(values.iter().flat_map(|v| v.to_le_bytes())),
            StoreAs::F16 => out.extend(
                values
                    .iter()
                    .flat_map(|v| half::f16::from_f32(*v).to_le_bytes()),
            ),
        }
    }

    fn dtype(self) -> safetensors::Dtype {
        match self {
            StoreAs::F32 => safetensors::Dtype::F32,
            StoreAs::F16 => safetensors::Dtype::F16,
        }
    }

    /// The largest magnitude stored as a finite value (f16: 65504).
    pub fn largest(self) -> f32 {
        match self {
            StoreAs::F32 => f32::MAX,
            StoreAs::F16 => half::f16::MAX.to_f32(),
        }
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
        let (header_bytes, header) =
            SafeTensors::read_metadata(bytes).map_err(|e| container_error(bytes, label, &e))?;
        // `read_metadata` checked that prefix + header + the tensors' extent is the whole buffer.
        let data = &bytes[PREFIX_BYTES + header_bytes..];
        let mut tensors = BTreeMap::new();
        let mut dtypes = BTreeMap::new();
        // Offset order: the first unsupported tensor reported is the same on every run.
        for name in header.offset_keys() {
            let Some(info) = header.info(&name) else {
                continue;
            };
            let dtype = Dtype::from_safetensors(info.dtype).ok_or_else(|| {
                WeightsError::UnsupportedDtype {
                    file: label.to_string(),
                    tensor: name.clone(),
                    dtype: info.dtype.to_string(),
                }
            })?;
            let (start, end) = info.data_offsets;
            let tensor = Tensor {
                shape: info.shape.clone(),
                data: dtype.to_f32(&data[start..end]),
            };
            dtypes.insert(name.clone(), dtype);
            tensors.insert(name, tensor);
        }
        let metadata = header
            .metadata()
            .as_ref()
            .map(|m| m.iter().map(|(k, v)| (k.clone(), v.clone())).collect())
            .unwrap_or_default();
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

/// A container error of the `safetensors` crate as a [`WeightsError::Format`] naming `label`.
fn container_error(bytes: &[u8], label: &str, e: &SafeTensorError) -> WeightsError {
    let available = bytes.len().saturating_sub(PREFIX_BYTES);
    let reason = match e {
        SafeTensorError::HeaderTooSmall => format!(
            "{} bytes is shorter than the {PREFIX_BYTES}-byte length prefix",
            bytes.len()
        ),
        SafeTensorError::HeaderTooLarge | SafeTensorError::InvalidHeaderLength => format!(
            "header length {} exceeds the {available} bytes after the prefix (or the \
             {MAX_HEADER_BYTES}-byte limit)",
            header_len(bytes).unwrap_or_default()
        ),
        SafeTensorError::InvalidOffset(name) => format!(
            "tensor `{name}`: data_offsets leave a gap before it or overlap the previous tensor"
        ),
        SafeTensorError::TensorInvalidInfo
        | SafeTensorError::ValidationOverflow
        | SafeTensorError::MisalignedSlice
        | SafeTensorError::MetadataIncompleteBuffer => {
            extent_error(bytes).unwrap_or_else(|| e.to_string())
        }
        other => other.to_string(),
    };
    WeightsError::Format {
        file: label.to_string(),
        reason,
    }
}

/// Names the tensor behind a size or extent error, which the crate reports without a name:
/// the first tensor, in offset order, whose shape overflows, whose byte range is not the size
/// its shape and dtype imply, or that ends past the data section. Only called after the crate
/// has parsed the header (so every entry is a valid [`TensorInfo`]) and rejected it.
fn extent_error(bytes: &[u8]) -> Option<String> {
    let header_end = usize::try_from(header_len(bytes)?)
        .ok()?
        .checked_add(PREFIX_BYTES)?;
    let header = bytes.get(PREFIX_BYTES..header_end)?;
    let data_len = bytes.len() - header_end;
    let mut entries: HashMap<String, serde_json::Value> = serde_json::from_slice(header).ok()?;
    entries.remove("__metadata__");
    let mut infos: Vec<(String, TensorInfo)> = entries
        .into_iter()
        .map(|(name, v)| Some((name, serde_json::from_value(v).ok()?)))
        .collect::<Option<_>>()?;
    infos.sort_by(|a, b| (a.1.data_offsets, &a.0).cmp(&(b.1.data_offsets, &b.0)));
    let mut covered = 0;
    for (name, info) in &infos {
        let (start, end) = info.data_offsets;
        let (shape, dtype) = (&info.shape, info.dtype);
        let bits = shape
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .and_then(|n| n.checked_mul(dtype.bitsize()));
        let reason = match bits {
            None => format!("shape {shape:?} overflows the address space"),
            Some(bits) if end.checked_sub(start) != Some(bits / 8) || bits % 8 != 0 => format!(
                "data_offsets [{start}, {end}] do not span the {} bytes of shape {shape:?} {dtype}",
                bits / 8
            ),
            Some(_) if end > data_len => {
                format!("ends at byte {end} but the data section has only {data_len} bytes")
            }
            Some(_) => {
                covered = end;
                continue;
            }
        };
        return Some(format!("tensor `{name}`: {reason}"));
    }
    (covered != data_len)
        .then(|| format!("tensors cover {covered} bytes but the data section has {data_len} bytes"))
}

/// The header length the prefix claims, in bytes; `None` for a file shorter than the prefix.
fn header_len(bytes: &[u8]) -> Option<u64> {
    Some(u64::from_le_bytes(
        bytes.get(..PREFIX_BYTES)?.try_into().ok()?,
    ))
}

/// Serialises tensors as an F32 safetensors file with the given `__metadata__` (omitted when
/// empty), through the `safetensors` crate: tensors in name order, the header padded with
/// spaces to a multiple of 8 bytes. With more than one metadata entry their order in the header
/// is the crate's (a hash map's), so only files with at most one entry are byte-reproducible.
pub fn write_safetensors(
    tensors: &BTreeMap<String, Tensor>,
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<u8>> {
    write_safetensors_as(tensors, metadata, StoreAs::F32)
}

/// [`write_safetensors`] with every tensor stored as `dtype`.
pub fn write_safetensors_as(
    tensors: &BTreeMap<String, Tensor>,
    metadata: &BTreeMap<String, String>,
    dtype: StoreAs,
) -> Result<Vec<u8>> {
    let views = tensors
        .iter()
        .map(|(n, t)| (n, StoredView(t.view(), dtype)));
    safetensors::serialize(views, header_metadata(metadata))
        .map_err(|e| WeightsError::Serialize(e.to_string()))
}

/// [`write_safetensors_as`] of borrowed tensors, streamed into `out`: the same bytes, without
/// a copy of the tensors or a buffer of the file (values are converted a block at a time).
/// The header is the crate's `Metadata`, laid out as `safetensors::serialize` lays it out
/// (a little-endian `u64` length, then the JSON padded with spaces to a multiple of 8 bytes);
/// a test checks the two writers agree byte for byte.
pub fn write_safetensors_to(
    out: &mut impl std::io::Write,
    tensors: &BTreeMap<String, TensorView<'_>>,
    metadata: &BTreeMap<String, String>,
    dtype: StoreAs,
) -> Result<()> {
    let serialize = |e: String| WeightsError::Serialize(e);
    let mut offset = 0;
    let infos = tensors
        .iter()
        .map(|(name, t)| {
            let n = t.data.len() * dtype.bytes();
            offset += n;
            let info = TensorInfo {
                dtype: dtype.dtype(),
                shape: t.shape.to_vec(),
                data_offsets: (offset - n, offset),
            };
            (name.clone(), info)
        })
        .collect();
    let header = safetensors::tensor::Metadata::new(header_metadata(metadata), infos)
        .map_err(|e| serialize(e.to_string()))?;
    let mut header = serde_json::to_vec(&header).map_err(|e| serialize(e.to_string()))?;
    header.resize(header.len().next_multiple_of(PREFIX_BYTES), b' ');
    if header.len() > MAX_HEADER_BYTES {
        return Err(serialize(format!("header of {} bytes", header.len())));
    }
    let io = |e: std::io::Error| serialize(e.to_string());
    out.write_all(&(header.len() as u64).to_le_bytes())
        .and_then(|()| out.write_all(&header))
        .map_err(io)?;
    /// Values converted per write.
    const BLOCK: usize = 1 << 16;
    let mut bytes = Vec::with_capacity(BLOCK * dtype.bytes());
    for t in tensors.values() {
        for block in t.data.chunks(BLOCK) {
            bytes.clear();
            dtype.encode(block, &mut bytes);
            out.write_all(&bytes).map_err(io)?;
        }
    }
    Ok(())
}

/// The crate's `__metadata__` map (`None` when empty, so no empty object is written).
fn header_metadata(metadata: &BTreeMap<String, String>) -> Option<HashMap<String, String>> {
    (!metadata.is_empty()).then(|| {
        metadata
            .iter()
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect()
    })
}
