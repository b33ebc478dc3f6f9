//! JPEG inputs as phones write them (issue 19 classes 2 and 3): a file cut short is an error,
//! not a grey fill, and the EXIF orientation is applied.

use image::codecs::jpeg::JpegEncoder;
use nam_ggx::imageio::{FileKind, decode_rgb};
use std::path::Path;

const SIDE: usize = 32;

/// A 32×32 baseline JPEG: black with a white 16×16 block in the top-left corner.
fn corner_jpeg() -> Vec<u8> {
    let mut px = vec![0u8; SIDE * SIDE * 3];
    for i in 0..16 {
        for j in 0..16 {
            px[(i * SIDE + j) * 3..(i * SIDE + j) * 3 + 3].copy_from_slice(&[255; 3]);
        }
    }
    let mut out = Vec::new();
    JpegEncoder::new_with_quality(&mut out, 95)
        .encode(
            &px,
            SIDE as u32,
            SIDE as u32,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap_or_else(|e| panic!("{e}"));
    out
}

/// `jpeg` with an APP1 EXIF segment (big-endian TIFF, one IFD entry: Orientation = `o`)
/// inserted after SOI.
fn with_orientation(jpeg: &[u8], o: u16) -> Vec<u8> {
    let mut tiff = b"MM\0\x2a\0\0\0\x08".to_vec();
    tiff.extend_from_slice(&[0, 1, 0x01, 0x12, 0, 3, 0, 0, 0, 1]);
    tiff.extend_from_slice(&o.to_be_bytes());
    tiff.extend_from_slice(&[0, 0, 0, 0, 0, 0]);
    let mut app1 = b"Exif\0\0".to_vec();
    app1.extend_from_slice(&tiff);
    let len = (app1.len() + 2) as u16;
    let mut out = jpeg[..2].to_vec();
    out.extend_from_slice(&[0xFF, 0xE1]);
    out.extend_from_slice(&len.to_be_bytes());
    out.extend_from_slice(&app1);
    out.extend_from_slice(&jpeg[2..]);
    out
}

fn decode(bytes: &[u8]) -> nam_ggx::Result<nam_ggx::RgbImage<f32>> {
    decode_rgb(bytes, FileKind::Ldr, Path::new("test.jpg"))
}

#[test]
fn truncated_jpegs_are_errors_and_complete_ones_load() {
    let full = corner_jpeg();
    assert!(decode(&full).is_ok());
    for cut in [full.len() / 3, full.len() / 2, full.len() - 2] {
        let err = decode(&full[..cut]).expect_err("a cut JPEG must not decode");
        assert!(
            err.to_string().contains("end-of-image marker"),
            "cut at {cut}: {err}"
        );
    }
    // Cut inside the headers (before the scan) too.
    let err = decode(&full[..40]).expect_err("headers only");
    assert!(err.to_string().contains("end-of-image marker"), "{err}");
    // Bytes after EOI (phones append data there) are fine.
    let mut trailing = full.clone();
    trailing.extend_from_slice(b"appended by a phone");
    assert!(decode(&trailing).is_ok());
}

#[test]
fn exif_orientation_is_applied_like_a_viewer_does() {
    let plain = decode(&corner_jpeg()).unwrap_or_else(|e| panic!("{e}"));
    let bright = |img: &nam_ggx::RgbImage<f32>, i: usize, j: usize| img.pixel(i, j)[0] > 0.5;
    assert!(bright(&plain, 4, 4) && !bright(&plain, 4, SIDE - 5));
    // Orientation 6: stored rotated; shown turned 90° clockwise, the top-left block ends up
    // top-right. 3: 180°, bottom-right. 1: as stored.
    for (o, (i, j)) in [
        (1, (4, 4)),
        (6, (4, SIDE - 5)),
        (3, (SIDE - 5, SIDE - 5)),
        (8, (SIDE - 5, 4)),
    ] {
        let img = decode(&with_orientation(&corner_jpeg(), o)).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            bright(&img, i, j),
            "orientation {o}: the block is not at ({i}, {j})"
        );
        assert!(!bright(&img, SIDE - 1 - i, SIDE - 1 - j), "orientation {o}");
    }
}
