//! A plain interleaved RGB image buffer and file I/O for it (PNG/JPEG via `image`,
//! OpenEXR via `exr`).
//!
//! Reading returns the values *as stored*: LDR files give encoded values in [0, 1]
//! (8- and 16-bit PNG divide by 255 / 65535; no transfer curve is undone here), EXR files give
//! linear f32 values. Callers decide what the values mean (gamma, sRGB, linear).

use crate::error::{GgxError, Result};
use crate::float::Float;
use std::io::Cursor;
use std::path::Path;

/// An `height`×`width` RGB image, row-major, channels interleaved (`data[(i·W + j)·3 + c]`).
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

impl<T: Float> RgbImage<T> {
    /// A black `height`×`width` image. Errors if either side is 0.
    pub fn zeros(height: usize, width: usize) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(GgxError::Empty { what: "image" });
        }
        Ok(Self {
            width,
            height,
            data: vec![T::ZERO; width * height * 3],
        })
    }

    /// Wraps data whose size the caller computed from a valid non-empty size.
    pub(crate) fn from_parts(height: usize, width: usize, data: Vec<T>) -> Self {
        debug_assert!(width > 0 && height > 0 && data.len() == width * height * 3);
        Self {
            width,
            height,
            data,
        }
    }

    /// Wraps `height`×`width` interleaved RGB data; errors if empty or if
    /// `data.len() != height·width·3`.
    pub fn from_vec(height: usize, width: usize, data: Vec<T>) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(GgxError::Empty { what: "image" });
        }
        let expected = width * height * 3;
        if data.len() != expected {
            return Err(GgxError::SizeMismatch {
                what: "RGB image buffer",
                expected,
                got: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Interleaved RGB values, row-major.
    pub fn data(&self) -> &[T] {
        &self.data
    }

    /// Mutable interleaved RGB values, row-major.
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Consumes the image, returning its buffer.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// The pixel at row `i`, column `j` (panics if out of bounds, like slice indexing).
    pub fn pixel(&self, i: usize, j: usize) -> [T; 3] {
        let k = (i * self.width + j) * 3;
        [self.data[k], self.data[k + 1], self.data[k + 2]]
    }

    /// Overwrites the pixel at row `i`, column `j`.
    pub fn set_pixel(&mut self, i: usize, j: usize, v: [T; 3]) {
        let k = (i * self.width + j) * 3;
        self.data[k..k + 3].copy_from_slice(&v);
    }

    /// Converts every value to another float type.
    pub fn cast<U: Float>(&self) -> RgbImage<U> {
        RgbImage {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|v| U::from_f64(v.to_f64())).collect(),
        }
    }

    /// Applies `f` to every value.
    pub fn map(&self, f: impl Fn(T) -> T) -> Self {
        Self {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| f(v)).collect(),
        }
    }

    /// Row `i` and column `j` of the first non-finite value, if any.
    pub fn first_non_finite(&self) -> Option<(usize, usize)> {
        self.data
            .iter()
            .position(|v| !v.is_finite())
            .map(|k| (k / 3 / self.width, (k / 3) % self.width))
    }
}

/// How a file stores its values, decided by the extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// `.exr`: linear f32 values, no transfer curve.
    Exr,
    /// `.png`, `.jpg`, `.jpeg`: 8/16-bit encoded values in [0, 1].
    Ldr,
}

impl FileKind {
    /// The kind of a path, by its (case-insensitive) extension.
    pub fn of(path: &Path) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("exr") => Ok(FileKind::Exr),
            Some("png" | "jpg" | "jpeg") => Ok(FileKind::Ldr),
            _ => Err(GgxError::UnsupportedFormat {
                path: path.to_path_buf(),
            }),
        }
    }
}

/// Largest image file read (bytes): above any compressed 64 Mpx ([`MAX_IMAGE_PIXELS`]) PNG,
/// JPEG or EXR; checked before reading.
pub const MAX_IMAGE_FILE_BYTES: u64 = 512 << 20;

/// Reads a whole file of at most `max_bytes`, checking before reading that it is a regular
/// file (a symlink to `/dev/zero`, a FIFO or a directory is refused) and not larger; reads at
/// most `max_bytes + 1` bytes even if the file grows meanwhile. `what` names the kind of file
/// in the error. The one bounded read of nam: images here, models and materials in the facade.
pub fn read_bounded(path: &Path, max_bytes: u64, what: &str) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("not a regular file (a directory, device or pipe); expected {what}"),
        ));
    }
    let too_big = |len: u64| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{len} bytes is more than {what} may be ({max_bytes} bytes, {} MiB)",
                max_bytes >> 20
            ),
        )
    };
    if meta.len() > max_bytes {
        return Err(too_big(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    std::fs::File::open(path)?
        .take(max_bytes + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Reads an RGB image file of at most [`MAX_IMAGE_FILE_BYTES`] (gray is expanded, alpha is
/// dropped). EXR values are checked to be finite (NaN/Inf → [`GgxError::NonFinite`] wrapped
/// with the path).
pub fn read_rgb(path: &Path) -> Result<(RgbImage<f32>, FileKind)> {
    let kind = FileKind::of(path)?;
    let bytes = read_bounded(path, MAX_IMAGE_FILE_BYTES, "an image file").map_err(|error| {
        GgxError::Io {
            path: path.to_path_buf(),
            error,
        }
    })?;
    Ok((decode_rgb(&bytes, kind, path)?, kind))
}

/// Decodes an image held in memory as `kind` (what [`read_rgb`] does after reading the file);
/// `label` names the source in errors. Corrupt or hostile bytes give an error, never a panic:
/// the declared size is checked against [`MAX_IMAGE_SIDE`] and [`MAX_IMAGE_PIXELS`] before any
/// pixel buffer is allocated, and non-finite values are rejected.
pub fn decode_rgb(bytes: &[u8], kind: FileKind, label: &Path) -> Result<RgbImage<f32>> {
    if bytes.is_empty() {
        return Err(GgxError::Decode {
            path: label.to_path_buf(),
            reason: "the file is empty (0 bytes)".into(),
        });
    }
    let img = match kind {
        FileKind::Ldr => decode_ldr(bytes),
        FileKind::Exr => decode_exr(bytes),
    }
    .map_err(|reason| GgxError::Decode {
        path: label.to_path_buf(),
        reason,
    })?;
    let (width, height, data) = img;
    let img = RgbImage::from_vec(height, width, data).map_err(|e| e.in_file(label))?;
    if let Some((row, col)) = img.first_non_finite() {
        return Err(GgxError::NonFinite {
            what: "image",
            row,
            col,
        }
        .in_file(label));
    }
    Ok(img)
}

/// Largest accepted image side when decoding, in pixels: a 4-panel SVBRDF file of 4096² maps is
/// 16384 wide. Checked against the file's *header* before any pixel buffer is allocated.
pub const MAX_IMAGE_SIDE: usize = 16_384;

/// Largest accepted pixel count when decoding (64 Mpx: a 16384×4096 4-panel file; 768 MiB as
/// f32 RGB). Checked against the header before any pixel buffer is allocated.
pub const MAX_IMAGE_PIXELS: usize = 1 << 26;

/// Largest decoder-internal buffer (the `image` crate's own limit, stated here so it is ours).
const MAX_DECODER_ALLOC: u64 = 1 << 30;

/// Rejects a declared size before anything of that size is allocated.
fn check_declared_size(width: usize, height: usize) -> std::result::Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!(
            "the header declares an empty {width}×{height} image"
        ));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(format!(
            "the header declares {width}×{height} (W×H) pixels; the largest supported side is \
             {MAX_IMAGE_SIDE}"
        ));
    }
    if width.saturating_mul(height) > MAX_IMAGE_PIXELS {
        return Err(format!(
            "the header declares {width}×{height} (W×H) pixels; at most {MAX_IMAGE_PIXELS} \
             pixels are supported"
        ));
    }
    Ok(())
}

/// A JPEG must reach its end-of-image marker: the decoder fills a file cut short with grey
/// and reports success. The marker segments are walked from SOI to the first start-of-scan;
/// in the entropy-coded data after it an `FF D9` pair can only be EOI (a data byte 0xFF is
/// always followed by 0x00, restart markers are FF D0–D7), so one must follow. EXIF
/// thumbnails sit inside an APP1 segment and are skipped with it.
fn check_jpeg_complete(bytes: &[u8]) -> std::result::Result<(), String> {
    const TRUNCATED: &str = "the JPEG ends before its end-of-image marker (truncated file?)";
    let mut i = 2;
    loop {
        while bytes.get(i) == Some(&0xFF) && bytes.get(i + 1) == Some(&0xFF) {
            i += 1; // fill bytes
        }
        let (Some(&0xFF), Some(&marker), Some(&hi), Some(&lo)) = (
            bytes.get(i),
            bytes.get(i + 1),
            bytes.get(i + 2),
            bytes.get(i + 3),
        ) else {
            return Err(TRUNCATED.into());
        };
        let next = i + 2 + usize::from(u16::from_be_bytes([hi, lo]));
        if marker == 0xDA {
            let scan = bytes.get(next..).ok_or(TRUNCATED)?;
            return if scan.windows(2).any(|w| w == [0xFF, 0xD9]) {
                Ok(())
            } else {
                Err(TRUNCATED.into())
            };
        }
        i = next;
    }
}

/// What an EXIF orientation does to the stored pixels, in words (`None`: nothing).
pub fn describe_orientation(o: ::image::metadata::Orientation) -> Option<&'static str> {
    use ::image::metadata::Orientation as O;
    match o {
        O::NoTransforms => None,
        O::Rotate90 => Some("rotated 90° clockwise"),
        O::Rotate180 => Some("rotated 180°"),
        O::Rotate270 => Some("rotated 90° counter-clockwise"),
        O::FlipHorizontal => Some("mirrored left-right"),
        O::FlipVertical => Some("mirrored top-bottom"),
        O::Rotate90FlipH => Some("rotated 90° clockwise and mirrored"),
        O::Rotate270FlipH => Some("rotated 90° counter-clockwise and mirrored"),
    }
}

/// Decodes PNG/JPEG as stored values in [0, 1], upright: the EXIF orientation (phone photos
/// are often stored sideways, Orientation = 6) is applied as a viewer would.
fn decode_ldr(bytes: &[u8]) -> std::result::Result<(usize, usize, Vec<f32>), String> {
    use ::image::ImageDecoder;
    let mut reader = ::image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    if reader.format() == Some(::image::ImageFormat::Jpeg) {
        check_jpeg_complete(bytes)?;
    }
    let mut limits = ::image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE as u32);
    limits.max_image_height = Some(MAX_IMAGE_SIDE as u32);
    limits.max_alloc = Some(MAX_DECODER_ALLOC);
    reader.limits(limits);
    // Header first: the declared size is checked before the decoder allocates its buffer.
    let mut decoder = reader.into_decoder().map_err(|e| e.to_string())?;
    let (w, h) = decoder.dimensions();
    check_declared_size(w as usize, h as usize)?;
    let orientation = decoder
        .orientation()
        .unwrap_or(::image::metadata::Orientation::NoTransforms);
    let mut dynamic = ::image::DynamicImage::from_decoder(decoder).map_err(|e| e.to_string())?;
    dynamic.apply_orientation(orientation);
    let rgb = dynamic.to_rgb32f();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    Ok((w, h, rgb.into_raw()))
}

fn decode_exr(bytes: &[u8]) -> std::result::Result<(usize, usize, Vec<f32>), String> {
    use exr::prelude::*;
    // Header first: the pixel closure below allocates width·height·3 floats, so every layer's
    // declared size is checked before the pixels are read.
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| e.to_string())?;
    for header in meta.headers.iter() {
        check_declared_size(header.layer_size.width(), header.layer_size.height())?;
    }
    type Pixels = (usize, Vec<f32>);
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res: Vec2<usize>, _: &RgbaChannels| -> Pixels {
                (res.width(), vec![0.0; res.width() * res.height() * 3])
            },
            |px: &mut Pixels, pos: Vec2<usize>, (r, g, b, _a): (f32, f32, f32, f32)| {
                let k = (pos.y() * px.0 + pos.x()) * 3;
                px.1[k] = r;
                px.1[k + 1] = g;
                px.1[k + 2] = b;
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| e.to_string())?;
    let size = image.layer_data.size;
    Ok((
        size.width(),
        size.height(),
        image.layer_data.channel_data.pixels.1,
    ))
}

/// PNG sample depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PngDepth {
    /// 8 bits per channel.
    Eight,
    /// 16 bits per channel.
    Sixteen,
}

/// Encodes an RGB image as PNG bytes. Values are *already encoded* (gamma/sRGB applied by the
/// caller), clamped to [0, 1] and rounded to the nearest code; NaN becomes 0.
pub fn encode_png(img: &RgbImage<f32>, depth: PngDepth) -> Result<Vec<u8>> {
    let (w, h) = dims_u32(img)?;
    // `as` saturates and maps NaN to 0.
    let q = |v: f32, max: f32| (v.clamp(0.0, 1.0) * max).round();
    let dynamic = match depth {
        PngDepth::Eight => {
            let raw: Vec<u8> = img.data().iter().map(|&v| quantize8(v)).collect();
            ::image::RgbImage::from_raw(w, h, raw).map(::image::DynamicImage::ImageRgb8)
        }
        PngDepth::Sixteen => {
            let raw: Vec<u16> = img.data().iter().map(|&v| q(v, 65535.0) as u16).collect();
            ::image::ImageBuffer::from_raw(w, h, raw).map(::image::DynamicImage::ImageRgb16)
        }
    };
    let dynamic = dynamic.ok_or_else(|| GgxError::InvalidArgument("PNG buffer size".into()))?;
    let mut out = Cursor::new(Vec::new());
    dynamic
        .write_to(&mut out, ::image::ImageFormat::Png)
        .map_err(|e| GgxError::Encode {
            path: "<png>".into(),
            reason: e.to_string(),
        })?;
    Ok(out.into_inner())
}

/// An encoded value in [0, 1] as the 8-bit level an 8-bit PNG stores: `round(255·v)` after
/// clamping (NaN gives 0).
#[inline]
pub fn quantize8(v: f32) -> u8 {
    // `as` saturates and maps NaN to 0.
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Encodes an RGB image as an OpenEXR file (f32 channels R, G, B; linear values as given).
pub fn encode_exr(img: &RgbImage<f32>) -> Result<Vec<u8>> {
    use exr::prelude::*;
    let (w, h) = (img.width(), img.height());
    let data = img.data();
    let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
        let k = (pos.y() * w + pos.x()) * 3;
        (data[k], data[k + 1], data[k + 2])
    });
    let image = Image::from_channels((w, h), channels);
    let mut out = Cursor::new(Vec::new());
    image
        .write()
        .to_buffered(&mut out)
        .map_err(|e| GgxError::Encode {
            path: "<exr>".into(),
            reason: e.to_string(),
        })?;
    Ok(out.into_inner())
}

/// Encodes for the file kind of `path` (`.png` with the given depth, or `.exr` f32) and
/// writes the file. Not atomic; the CLI has an atomic writer.
pub fn write_rgb(path: &Path, img: &RgbImage<f32>, depth: PngDepth) -> Result<()> {
    let bytes = encode_for_path(path, img, depth)?;
    std::fs::write(path, bytes).map_err(|error| GgxError::Io {
        path: path.to_path_buf(),
        error,
    })
}

/// Encodes `img` in the format named by the extension of `path`: `.exr` (f32, values as
/// given) or `.png` (values already encoded, clamped to [0, 1]). JPEG output is not offered.
pub fn encode_for_path(path: &Path, img: &RgbImage<f32>, depth: PngDepth) -> Result<Vec<u8>> {
    let with_path = |e: GgxError| match e {
        GgxError::Encode { reason, .. } => GgxError::Encode {
            path: path.to_path_buf(),
            reason,
        },
        e => e,
    };
    match FileKind::of(path)? {
        FileKind::Exr => encode_exr(img).map_err(with_path),
        FileKind::Ldr => {
            let is_png = path
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("png"));
            if !is_png {
                return Err(GgxError::UnsupportedFormat {
                    path: path.to_path_buf(),
                });
            }
            encode_png(img, depth).map_err(with_path)
        }
    }
}

fn dims_u32(img: &RgbImage<f32>) -> Result<(u32, u32)> {
    let w = u32::try_from(img.width())
        .map_err(|_| GgxError::InvalidArgument("image too wide for PNG".into()))?;
    let h = u32::try_from(img.height())
        .map_err(|_| GgxError::InvalidArgument("image too tall for PNG".into()))?;
    Ok((w, h))
}
