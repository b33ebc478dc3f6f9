//! Helpers shared by the nam-model integration tests: deterministic synthetic inputs.

use nam_model::ParamMap;

/// `len` values `((i·mul) mod modulus) / div − 1`: a fixed, non-trivial pattern without a
/// random generator.
pub fn pattern(len: usize, mul: usize, modulus: usize, div: f32) -> Vec<f32> {
    (0..len)
        .map(|i| ((i * mul % modulus) as f32) / div - 1.0)
        .collect()
}

/// An `h`×`w` map of 64 parameter channels filled with [`pattern`].
pub fn pattern_map(h: usize, w: usize, mul: usize, modulus: usize, div: f32) -> ParamMap {
    ParamMap {
        height: h,
        width: w,
        channels: 64,
        data: pattern(h * w * 64, mul, modulus, div),
    }
}
