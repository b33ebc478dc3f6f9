//! Structured hostile model files (issue #8.3), complementing the byte-level corruption of
//! `fuzz.rs`: well-formed safetensors whose JSON header carries hostile tensor entries (dtypes,
//! shapes with zero / huge / overflowing dimensions, offsets out of order or past the end) and
//! whose `config` metadata has hostile field values (zero, odd, huge or negative widths, empty
//! layer lists, 1000 octaves, NaN-like and negative epsilons, wrong types). Every input must
//! parse to `Ok` or `Err`, never panic. A bounded corpus run: fixed seed and count.

mod common;

use common::{micro_config, parse_never_panics, safetensors_bytes};
use nam_weights::{SplitMix64, Weights};
use serde_json::{Value, json};

/// Hostile JSON values for any field.
fn hostile_value(rng: &mut SplitMix64) -> Value {
    let xs = [
        json!(0),
        json!(1),
        json!(3),
        json!(-1),
        json!(65536),
        json!(65537),
        json!(4_294_967_296u64),
        json!(u64::MAX),
        json!(i64::MIN),
        json!(1e300),
        json!(-0.0),
        json!(1e-300),
        json!("nan"),
        json!(null),
        json!(true),
        json!([]),
        json!([0]),
        json!([1_000_000, 1_000_000, 3]),
        json!([27, 0, 4]),
        json!([u64::MAX, 2]),
        json!({}),
        json!("ldr"),
        json!("hdr"),
        json!("f16"),
    ];
    rng.pick(&xs).clone()
}

/// Splits a file into its JSON header and its data section.
fn split(bytes: &[u8]) -> (Value, Vec<u8>) {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let header = serde_json::from_slice(&bytes[8..8 + n]).expect("valid header JSON");
    (header, bytes[8 + n..].to_vec())
}

fn join(header: &Value, data: &[u8]) -> Vec<u8> {
    safetensors_bytes(&header.to_string(), data)
}

#[test]
fn hostile_headers_and_configs_give_errors_not_panics() {
    let good = Weights::random(micro_config(), 5)
        .expect("micro weights")
        .to_safetensors_bytes()
        .unwrap();
    let (header, data) = split(&good);
    let config: Value =
        serde_json::from_str(header["__metadata__"]["config"].as_str().expect("config"))
            .expect("config JSON");
    let fields: Vec<String> = config
        .as_object()
        .expect("object")
        .keys()
        .cloned()
        .collect();
    let tensors: Vec<String> = header
        .as_object()
        .expect("object")
        .keys()
        .filter(|k| *k != "__metadata__")
        .cloned()
        .collect();
    let mut rng = SplitMix64(0xFEED_5AFE);
    let t0 = std::time::Instant::now();
    let (mut tried, mut accepted) = (0usize, 0usize);
    assert!(
        parse_never_panics(&good, &mut tried),
        "the base file parses"
    );

    // 1. Config fields set to hostile values (one to three at a time), tensors intact.
    const CONFIGS: usize = 1500;
    for _ in 0..CONFIGS {
        let mut c = config.clone();
        for _ in 0..1 + rng.below(3) {
            let f = rng.pick(&fields).clone();
            c[f.as_str()] = hostile_value(&mut rng);
            if rng.below(4) == 0 && c["slopes"].is_object() {
                // A nested field (slopes.*), or a removed one.
                c["slopes"][*rng.pick(&["ha", "nd_enc", "render_hidden", "render_out"])] =
                    hostile_value(&mut rng);
            }
        }
        if rng.below(8) == 0 {
            let f = rng.pick(&fields).clone();
            c.as_object_mut().expect("object").remove(&f);
        }
        let mut h = header.clone();
        h["__metadata__"]["config"] = Value::String(c.to_string());
        accepted += usize::from(parse_never_panics(&join(&h, &data), &mut tried));
    }
    // 2. Tensor entries with hostile dtype, shape and offsets.
    let dtypes = [
        "F32", "F16", "BF16", "F64", "I8", "U8", "BOOL", "F8_E4M3", "f32", "", "X",
    ];
    const ENTRIES: usize = 2500;
    for _ in 0..ENTRIES {
        let mut h = header.clone();
        for _ in 0..1 + rng.below(2) {
            let t = rng.pick(&tensors).clone();
            if !h[t.as_str()].is_object() {
                continue; // replaced by a non-object earlier in this case
            }
            match rng.below(4) {
                0 => h[t.as_str()]["dtype"] = json!(rng.pick(&dtypes)),
                1 => {
                    let dims: Vec<Value> = (0..rng.below(5))
                        .map(|_| {
                            json!(*rng.pick(&[
                                0u64,
                                1,
                                2,
                                3,
                                7,
                                65_535,
                                1 << 32,
                                1 << 63,
                                u64::MAX
                            ]))
                        })
                        .collect();
                    h[t.as_str()]["shape"] = Value::Array(dims);
                }
                2 => {
                    let end = data.len() as u64;
                    let pick = |r: &mut SplitMix64| {
                        *r.pick(&[0, 1, 4, end / 2, end, end + 4, u64::MAX, 1 << 40])
                    };
                    h[t.as_str()]["data_offsets"] = json!([pick(&mut rng), pick(&mut rng)]);
                }
                _ => h[t.as_str()] = hostile_value(&mut rng),
            }
        }
        if rng.below(10) == 0 {
            h["__metadata__"] = hostile_value(&mut rng);
        }
        accepted += usize::from(parse_never_panics(&join(&h, &data), &mut tried));
    }
    eprintln!(
        "fuzz_headers: {tried} structured hostile model files parsed without a panic \
         ({accepted} accepted, {:.1} s)",
        t0.elapsed().as_secs_f64()
    );
    assert!(tried > 4_000, "{tried}");
}
