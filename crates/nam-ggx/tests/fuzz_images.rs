//! Hostile image bytes (issue #8.3): PNG, JPEG and EXR files that are truncated, bit-flipped,
//! re-checksummed after corruption, spliced, random, or whose headers declare absurd sizes must
//! give an error (or a valid image), never a panic, and never an allocation sized by an
//! unchecked header. A bounded corpus run: a fixed seed and a fixed number of cases (a few
//! seconds in debug), so CI runs it every time.
//!
//! The binary counts allocations with a wrapping global allocator: while hostile bytes are
//! decoded, the largest single allocation is recorded and must stay below what the decoder's
//! declared-size checks allow; for the "huge header" files it must stay tiny (they are rejected
//! from the header alone). Only one `#[test]` lives in this file so nothing else allocates
//! concurrently while the measurement is on.

use nam_ggx::RgbImage;
use nam_ggx::imageio::{
    FileKind, MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, decode_rgb, encode_exr, read_rgb,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Cursor;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, recording the largest single request.
struct Tracking;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards every call unchanged to `System`; only records sizes.
unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Tracking = Tracking;

/// Any single buffer a decoder may allocate for an image that passed the declared-size checks:
/// MAX_IMAGE_PIXELS RGBA values of 32-bit floats (the widest pixel type decoded).
const CHECKED_ALLOC_BOUND: usize = MAX_IMAGE_PIXELS * 16;

/// Largest single allocation allowed while decoding a file whose header declares an
/// oversized image: it must be rejected from the header (the test inputs are < 1 MiB).
const HEADER_REJECT_ALLOC_BOUND: usize = 8 << 20;

fn label() -> &'static Path {
    Path::new("<fuzz>")
}

/// Decodes `bytes` as `kind`, returning whether it was accepted; panics are test failures
/// that name the input.
fn decode(bytes: &[u8], kind: FileKind, what: &str, tried: &mut usize) -> bool {
    *tried += 1;
    let r = std::panic::catch_unwind(|| decode_rgb(bytes, kind, label()));
    match r {
        Err(_) => panic!(
            "{what}: decoder panicked on input #{tried} ({} bytes)",
            bytes.len()
        ),
        Ok(Ok(img)) => {
            assert!(img.width() <= MAX_IMAGE_SIDE && img.height() <= MAX_IMAGE_SIDE);
            assert!(
                img.data().iter().all(|v| v.is_finite()),
                "{what}: non-finite accepted"
            );
            true
        }
        Ok(Err(e)) => {
            assert!(
                e.to_string().contains("<fuzz>"),
                "{what}: error names no source: {e}"
            );
            false
        }
    }
}

fn encode(img: image::DynamicImage, format: image::ImageFormat) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).expect("encode seed");
    out.into_inner()
}

fn gradient(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 17) as u8, (y * 29) as u8, ((x ^ y) * 7) as u8])
    })
}

fn png_seeds() -> Vec<Vec<u8>> {
    let rgb = gradient(13, 7);
    let rgb16 = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(5, 9, |x, y| {
        image::Rgb([(x * 4000) as u16, (y * 7000) as u16, 65535])
    });
    let gray = image::GrayImage::from_fn(8, 8, |x, y| image::Luma([(x * y * 4) as u8]));
    let rgba = image::RgbaImage::from_fn(6, 6, |x, y| image::Rgba([x as u8 * 40, y as u8, 9, 200]));
    vec![
        encode(rgb.into(), image::ImageFormat::Png),
        encode(rgb16.into(), image::ImageFormat::Png),
        encode(gray.into(), image::ImageFormat::Png),
        encode(rgba.into(), image::ImageFormat::Png),
        encode(gradient(1, 1).into(), image::ImageFormat::Png),
    ]
}

fn jpeg_seeds() -> Vec<Vec<u8>> {
    vec![
        encode(gradient(16, 16).into(), image::ImageFormat::Jpeg),
        encode(gradient(9, 3).into(), image::ImageFormat::Jpeg),
    ]
}

fn exr_seeds() -> Vec<Vec<u8>> {
    use exr::prelude::*;
    let img = RgbImage::from_vec(
        4,
        6,
        (0..72).map(|k| (k as f32 * 0.37).sin() * 100.0).collect(),
    )
    .expect("seed image");
    let plain = encode_exr(&img).expect("encode exr");
    let mut out = vec![plain];
    for encoding in [Encoding::SMALL_LOSSLESS, Encoding::FAST_LOSSLESS] {
        let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
            let v = (p.x() * 3 + p.y()) as f32 * 0.5;
            (v, -v, f16::from_f32(v * 2.0))
        });
        let image = Image::from_encoded_channels((11, 5), encoding, channels);
        let mut buf = Cursor::new(Vec::new());
        image.write().to_buffered(&mut buf).expect("encode exr");
        out.push(buf.into_inner());
    }
    out
}

/// CRC-32 (IEEE), as PNG chunks use.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ 0xEDB8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// Recomputes every PNG chunk CRC that lies inside the buffer, so corruption reaches the
/// chunk parsers instead of stopping at the checksum.
fn fix_png_crcs(b: &mut [u8]) {
    let mut pos = 8;
    while pos + 12 <= b.len() {
        let len = u32::from_be_bytes([b[pos], b[pos + 1], b[pos + 2], b[pos + 3]]) as usize;
        let Some(end) = (pos + 8).checked_add(len) else {
            return;
        };
        if end + 4 > b.len() {
            return;
        }
        let crc = crc32(&b[pos + 4..end]);
        b[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        pos = end + 4;
    }
}

/// A PNG whose IHDR declares `w`×`h` (valid CRC), with the seed's pixel data.
fn png_declaring(seed: &[u8], w: u32, h: u32) -> Vec<u8> {
    let mut b = seed.to_vec();
    b[16..20].copy_from_slice(&w.to_be_bytes());
    b[20..24].copy_from_slice(&h.to_be_bytes());
    fix_png_crcs(&mut b);
    b
}

/// A JPEG whose SOF marker declares `w`×`h`.
fn jpeg_declaring(seed: &[u8], w: u16, h: u16) -> Vec<u8> {
    let mut b = seed.to_vec();
    let sof = (0..b.len() - 1)
        .find(|&k| b[k] == 0xFF && matches!(b[k + 1], 0xC0..=0xC2))
        .expect("SOF marker");
    b[sof + 5..sof + 7].copy_from_slice(&h.to_be_bytes());
    b[sof + 7..sof + 9].copy_from_slice(&w.to_be_bytes());
    b
}

/// An EXR whose `dataWindow` (and `displayWindow`) attributes declare (x0, y0)..=(x1, y1).
fn exr_declaring(seed: &[u8], x0: i32, y0: i32, x1: i32, y1: i32) -> Vec<u8> {
    let mut b = seed.to_vec();
    for name in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
        let at = b
            .windows(name.len())
            .position(|w| w == name)
            .expect("window attribute")
            + name.len()
            + 4; // the attribute's byte size
        for (k, v) in [x0, y0, x1, y1].into_iter().enumerate() {
            b[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
    }
    b
}

fn mutate(rng: &mut Pcg64, seed: &[u8]) -> Vec<u8> {
    let mut b = seed.to_vec();
    match rng.random_range(0..6) {
        // Bit flips, biased towards the header.
        0 | 1 => {
            for _ in 0..rng.random_range(1..6) {
                let head = b.len().min(64);
                let pos = if rng.random_bool(0.6) {
                    rng.random_range(0..head)
                } else {
                    rng.random_range(0..b.len())
                };
                b[pos] ^= 1 << rng.random_range(0..8);
            }
        }
        // Interesting byte values.
        2 => {
            for _ in 0..rng.random_range(1..4) {
                let pos = rng.random_range(0..b.len());
                b[pos] = [0x00, 0xFF, 0x7F, 0x80, 0x01, 0xFE][rng.random_range(0..6)];
            }
        }
        // Truncation.
        3 => b.truncate(rng.random_range(0..b.len())),
        // Delete or duplicate a span.
        4 => {
            let a = rng.random_range(0..b.len());
            let n = rng.random_range(1..=(b.len() - a).min(32));
            if rng.random_bool(0.5) {
                b.drain(a..a + n);
            } else {
                let span: Vec<u8> = b[a..a + n].to_vec();
                b.splice(a..a, span);
            }
        }
        // Random 32-bit word (sizes, offsets, lengths).
        _ => {
            if b.len() >= 4 {
                let pos = rng.random_range(0..b.len() - 3);
                let w: u32 = match rng.random_range(0..4) {
                    0 => u32::MAX,
                    1 => 0x7FFF_FFFF,
                    2 => 1 << rng.random_range(0..32),
                    _ => rng.random(),
                };
                b[pos..pos + 4].copy_from_slice(&w.to_be_bytes());
            }
        }
    }
    b
}

#[test]
fn hostile_image_bytes_give_errors_never_panics_nor_header_sized_allocations() {
    let mut rng = Pcg64::seed_from_u64(0x5EED_1A6E);
    let mut tried = 0usize;
    let mut accepted = 0usize;
    let png = png_seeds();
    let jpeg = jpeg_seeds();
    let exr = exr_seeds();

    // The seeds decode (otherwise the corpus tests nothing).
    for (seeds, kind) in [
        (&png, FileKind::Ldr),
        (&jpeg, FileKind::Ldr),
        (&exr, FileKind::Exr),
    ] {
        for s in seeds.iter() {
            assert!(
                decode(s, kind, "seed", &mut tried),
                "a seed does not decode"
            );
        }
    }

    // 1. Headers declaring absurd sizes, each checksum-valid: rejected from the header.
    let p = &png[0];
    let e = &exr[0];
    let j = &jpeg[0];
    let side = MAX_IMAGE_SIDE as u32;
    let huge: Vec<(String, Vec<u8>, FileKind)> = vec![
        (
            "png 2^31-1 square".into(),
            png_declaring(p, 0x7FFF_FFFF, 0x7FFF_FFFF),
            FileKind::Ldr,
        ),
        (
            "png u32::MAX wide".into(),
            png_declaring(p, u32::MAX, 1),
            FileKind::Ldr,
        ),
        (
            "png 100000²".into(),
            png_declaring(p, 100_000, 100_000),
            FileKind::Ldr,
        ),
        (
            "png side+1 wide".into(),
            png_declaring(p, side + 1, 1),
            FileKind::Ldr,
        ),
        (
            "png side+1 tall".into(),
            png_declaring(p, 1, side + 1),
            FileKind::Ldr,
        ),
        (
            "png side² (too many pixels)".into(),
            png_declaring(p, side, side),
            FileKind::Ldr,
        ),
        ("png 0 wide".into(), png_declaring(p, 0, 7), FileKind::Ldr),
        (
            "jpeg 65535²".into(),
            jpeg_declaring(j, 65535, 65535),
            FileKind::Ldr,
        ),
        (
            "jpeg 65535×1".into(),
            jpeg_declaring(j, 65535, 1),
            FileKind::Ldr,
        ),
        (
            "jpeg 20000×20000".into(),
            jpeg_declaring(j, 20_000, 20_000),
            FileKind::Ldr,
        ),
        (
            "exr 1e9²".into(),
            exr_declaring(e, 0, 0, 1_000_000_000, 1_000_000_000),
            FileKind::Exr,
        ),
        (
            "exr i32 extremes".into(),
            exr_declaring(e, i32::MIN, i32::MIN, i32::MAX, i32::MAX),
            FileKind::Exr,
        ),
        (
            "exr 100000²".into(),
            exr_declaring(e, 0, 0, 99_999, 99_999),
            FileKind::Exr,
        ),
        (
            "exr side+1 wide".into(),
            exr_declaring(e, 0, 0, side as i32, 0),
            FileKind::Exr,
        ),
        (
            "exr side² (too many pixels)".into(),
            exr_declaring(e, 0, 0, side as i32 - 1, side as i32 - 1),
            FileKind::Exr,
        ),
        (
            "exr negative window".into(),
            exr_declaring(e, 10, 10, 0, 0),
            FileKind::Exr,
        ),
    ];
    for (what, bytes, kind) in &huge {
        LARGEST.store(0, Ordering::Relaxed);
        assert!(!decode(bytes, *kind, what, &mut tried), "{what}: accepted");
        let largest = LARGEST.load(Ordering::Relaxed);
        assert!(
            largest <= HEADER_REJECT_ALLOC_BOUND,
            "{what}: allocated {largest} bytes before rejecting the header"
        );
    }
    // Through the file API too (the path ends up in the message).
    let dir = tempfile::tempdir().expect("tmp");
    for (name, bytes) in [
        ("huge.png", &huge[0].1),
        ("huge.exr", &huge[10].1),
        ("huge.jpg", &huge[7].1),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).expect("write");
        tried += 1;
        let err = read_rgb(&path).unwrap_err().to_string();
        assert!(err.contains(name), "{err}");
    }

    // 2. Every truncation of each seed's first 128 bytes (headers and first chunks).
    for (seeds, kind) in [
        (&png, FileKind::Ldr),
        (&jpeg, FileKind::Ldr),
        (&exr, FileKind::Exr),
    ] {
        for s in seeds.iter() {
            for len in 0..s.len().min(128) {
                decode(&s[..len], kind, "truncated", &mut tried);
            }
        }
    }

    // 3. Random mutations (PNG ones also with re-computed CRCs so they reach the parsers).
    LARGEST.store(0, Ordering::Relaxed);
    const MUTATIONS_PER_FORMAT: usize = 5000;
    for _ in 0..MUTATIONS_PER_FORMAT {
        let s = &png[rng.random_range(0..png.len())];
        let mut b = mutate(&mut rng, s);
        if rng.random_bool(0.7) {
            fix_png_crcs(&mut b);
        }
        accepted += usize::from(decode(&b, FileKind::Ldr, "png mutation", &mut tried));
        let s = &jpeg[rng.random_range(0..jpeg.len())];
        accepted += usize::from(decode(
            &mutate(&mut rng, s),
            FileKind::Ldr,
            "jpeg mutation",
            &mut tried,
        ));
        let s = &exr[rng.random_range(0..exr.len())];
        accepted += usize::from(decode(
            &mutate(&mut rng, s),
            FileKind::Exr,
            "exr mutation",
            &mut tried,
        ));
    }
    // 4. Random bytes behind each format's magic number, and with none.
    let magics: [(&[u8], FileKind); 4] = [
        (b"\x89PNG\r\n\x1a\n", FileKind::Ldr),
        (b"\xFF\xD8\xFF", FileKind::Ldr),
        (b"\x76\x2f\x31\x01", FileKind::Exr),
        (b"", FileKind::Exr),
    ];
    for _ in 0..1000 {
        for (magic, kind) in magics {
            let n = rng.random_range(0..256);
            let mut b = magic.to_vec();
            b.extend((0..n).map(|_| rng.random::<u8>()));
            accepted += usize::from(decode(&b, kind, "random", &mut tried));
        }
    }
    let largest = LARGEST.load(Ordering::Relaxed);
    assert!(
        largest <= CHECKED_ALLOC_BOUND,
        "a mutated file made the decoder allocate {largest} bytes"
    );
    eprintln!(
        "fuzz_images: {tried} inputs decoded without a panic ({accepted} mutated inputs \
         accepted as valid images); largest single allocation during mutations {largest} bytes"
    );
    assert!(tried > 20_000, "{tried}");
}
