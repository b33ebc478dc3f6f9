//! "Error, never panic": thousands of corrupted model files must each produce
//! `Ok` or `Err`, never a panic, and never an allocation beyond the file size.

mod common;

use common::{micro_config, parse_never_panics, safetensors_bytes};
use nam_weights::{TensorFile, Weights, WeightsError};

/// xorshift64*: deterministic corruption positions.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

#[test]
fn corrupted_files_give_errors_not_panics() {
    let good = Weights::random(micro_config(), 11)
        .unwrap()
        .to_safetensors_bytes()
        .unwrap();
    Weights::from_bytes(&good, "base").unwrap();
    let header_end = 8 + u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut tried = 0usize;

    // Every truncation length inside the header, a sample beyond it.
    for len in 0..header_end.min(good.len()) {
        parse_never_panics(&good[..len], &mut tried);
    }
    for _ in 0..500 {
        let len = rng.below(good.len());
        parse_never_panics(&good[..len], &mut tried);
    }
    // Bit flips: mostly in the header (structure), some in the data.
    for i in 0..3000 {
        let mut b = good.clone();
        let flips = 1 + rng.below(4);
        for _ in 0..flips {
            let pos = if i % 4 == 0 {
                rng.below(b.len())
            } else {
                rng.below(header_end)
            };
            b[pos] ^= 1 << rng.below(8);
        }
        parse_never_panics(&b, &mut tried);
    }
    // Length prefixes that overshoot, undershoot or are absurd.
    for claim in [
        0u64,
        1,
        7,
        (header_end - 9) as u64,
        (header_end - 7) as u64,
        good.len() as u64,
        u32::MAX as u64,
        u64::MAX,
        1 << 40,
    ] {
        let mut b = good.clone();
        b[..8].copy_from_slice(&claim.to_le_bytes());
        parse_never_panics(&b, &mut tried);
    }
    // Random byte strings with a plausible prefix.
    for _ in 0..500 {
        let n = rng.below(200);
        let mut b: Vec<u8> = (0..n + 8).map(|_| rng.next() as u8).collect();
        b[..8].copy_from_slice(&(n as u64).to_le_bytes());
        parse_never_panics(&b, &mut tried);
    }
    println!("fuzz: {tried} corrupted inputs parsed without panicking");
    assert!(tried > 4000);
}

fn raw_file(header: &str, data_len: usize) -> Vec<u8> {
    safetensors_bytes(header, &vec![0; data_len])
}

#[test]
fn header_claiming_a_terabyte_tensor_is_rejected_before_allocating() {
    // 2^38 f32 = 1 TiB, in a file of a few hundred bytes. If the reader allocated
    // first, this test would abort with an allocation failure instead of failing.
    let n: u64 = 1 << 38;
    let h = format!(
        r#"{{"big":{{"dtype":"F32","shape":[{n}],"data_offsets":[0,{}]}}}}"#,
        n * 4
    );
    let err = TensorFile::from_bytes(&raw_file(&h, 16), "tb").unwrap_err();
    assert!(matches!(err, WeightsError::Format { .. }), "{err}");
    assert!(err.to_string().contains("big"), "{err}");
}

#[test]
fn shape_products_that_overflow_are_errors() {
    let h = r#"{"t":{"dtype":"F32","shape":[4294967296,4294967296,16],"data_offsets":[0,0]}}"#;
    let err = TensorFile::from_bytes(&raw_file(h, 0), "ovf").unwrap_err();
    assert!(err.to_string().contains("overflow"), "{err}");
    assert!(err.to_string().contains("tensor `t`"), "{err}");
}

#[test]
fn overlapping_or_gapped_offsets_are_errors() {
    let overlap = r#"{"a":{"dtype":"F32","shape":[2],"data_offsets":[0,8]},"b":{"dtype":"F32","shape":[2],"data_offsets":[4,12]}}"#;
    let gap = r#"{"a":{"dtype":"F32","shape":[1],"data_offsets":[0,4]},"b":{"dtype":"F32","shape":[1],"data_offsets":[8,12]}}"#;
    let trailing = r#"{"a":{"dtype":"F32","shape":[1],"data_offsets":[0,4]}}"#;
    for (h, len, names) in [
        (overlap, 12, "tensor `b`"),
        (gap, 12, "tensor `b`"),
        (trailing, 8, "cover 4 bytes"),
    ] {
        let err = TensorFile::from_bytes(&raw_file(h, len), "off").unwrap_err();
        assert!(matches!(err, WeightsError::Format { .. }), "{err}");
        let msg = err.to_string();
        assert!(msg.starts_with("off: ") && msg.contains(names), "{msg}");
    }
}

#[test]
fn size_and_length_errors_name_the_tensor_and_the_sizes() {
    // 2 F32 values need 8 bytes, not 6.
    let short = r#"{"w":{"dtype":"F32","shape":[2],"data_offsets":[0,6]}}"#;
    let err = TensorFile::from_bytes(&raw_file(short, 6), "s").unwrap_err();
    assert!(
        err.to_string()
            .contains("tensor `w`: data_offsets [0, 6] do not span the 8 bytes"),
        "{err}"
    );
    let err = TensorFile::from_bytes(&[0; 5], "tiny").unwrap_err();
    assert!(err.to_string().contains("shorter than the 8-byte"), "{err}");
    let err = TensorFile::from_bytes(&raw_file("{}", 0)[..9], "cut").unwrap_err();
    assert!(
        err.to_string()
            .contains("header length 2 exceeds the 1 bytes"),
        "{err}"
    );
}

#[test]
fn deeply_nested_header_json_is_an_error_not_a_stack_overflow() {
    let h = format!("{}{}", "[".repeat(100_000), "]".repeat(100_000));
    let err = TensorFile::from_bytes(&raw_file(&h, 0), "deep").unwrap_err();
    assert!(matches!(err, WeightsError::Format { .. }), "{err}");
}
