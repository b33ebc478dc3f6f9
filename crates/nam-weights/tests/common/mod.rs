//! Helpers shared by the fuzz tests: a tiny model, raw safetensors assembly and a parse that
//! must not panic.

use nam_weights::{ModelConfig, Slopes, TensorFile, Weights};

/// A very small but complete architecture so each parse is cheap.
pub fn micro_config() -> ModelConfig {
    ModelConfig {
        width: 2,
        param_channels: 4,
        pe_octaves: 1,
        nd_enc: vec![27, 6, 4],
        render: vec![8, 6, 6, 3],
        slopes: Slopes {
            ha: 0.1,
            nd_enc: 0.01,
            render_hidden: 0.01,
            render_out: 0.001,
        },
        ..ModelConfig::standard(2)
    }
}

/// A safetensors file as bytes: the little-endian header length, the header, the data.
pub fn safetensors_bytes(header: &str, data: &[u8]) -> Vec<u8> {
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}

/// Parses `bytes` as a tensor file and as weights, counting the try in `tried`; panics (naming
/// the input) if either parser panicked. Returns whether both accepted it.
pub fn parse_never_panics(bytes: &[u8], tried: &mut usize) -> bool {
    *tried += 1;
    let r = std::panic::catch_unwind(|| {
        let a = TensorFile::from_bytes(bytes, "fuzz").is_ok();
        let b = Weights::from_bytes(bytes, "fuzz").is_ok();
        a && b
    });
    r.unwrap_or_else(|_| panic!("panicked on input #{tried} ({} bytes)", bytes.len()))
}
