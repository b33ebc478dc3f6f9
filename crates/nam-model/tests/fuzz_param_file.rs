//! Hostile `.nam` param-map files (issue #8.3): a saved material is user input to
//! `nam-cli relight`. Truncated, bit-flipped, re-sized and random files must give `Ok` or an
//! error, never a panic; headers declaring huge maps must be rejected before allocating.
//! A bounded corpus run (fixed seed and count).

use nam_model::ParamMap;
use nam_weights::SplitMix64;

fn sample() -> Vec<u8> {
    let (h, w, c) = (3, 2, 4);
    let map = ParamMap {
        height: h,
        width: w,
        channels: c,
        data: (0..h * w * c).map(|k| k as f32 * 0.25 - 1.0).collect(),
    };
    map.to_nam_bytes("ab12").unwrap()
}

fn parse(bytes: &[u8], tried: &mut usize) -> bool {
    *tried += 1;
    match std::panic::catch_unwind(|| ParamMap::from_nam_bytes(bytes, "fuzz")) {
        Err(_) => panic!(
            "from_nam_bytes panicked on input #{tried} ({} bytes)",
            bytes.len()
        ),
        Ok(Ok((m, _))) => {
            assert_eq!(m.data.len(), m.height * m.width * m.channels);
            assert!(m.data.iter().all(|v| v.is_finite()));
            true
        }
        Ok(Err(e)) => {
            assert!(e.to_string().contains("fuzz"), "error names no file: {e}");
            false
        }
    }
}

/// A `.nam` file with a hand-written header and `data_len` zero bytes of data.
fn raw(header: &str, data_len: usize) -> Vec<u8> {
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out.resize(out.len() + data_len, 0);
    out
}

#[test]
fn corrupted_param_files_give_errors_not_panics() {
    let good = sample();
    let (m, sha) = ParamMap::from_nam_bytes(&good, "good").expect("round trip");
    assert_eq!(
        (m.height, m.width, m.channels, sha.as_str()),
        (3, 2, 4, "ab12")
    );
    let header_end = 8 + u64::from_le_bytes(good[..8].try_into().expect("8 bytes")) as usize;
    let mut rng = SplitMix64(0x0BAD_F11E);
    let mut tried = 0usize;
    let mut accepted = 0usize;

    for len in 0..good.len() {
        accepted += usize::from(parse(&good[..len], &mut tried));
    }
    for i in 0..4000 {
        let mut b = good.clone();
        for _ in 0..1 + rng.below(4) {
            let pos = if i % 4 == 0 {
                rng.below(b.len())
            } else {
                rng.below(header_end)
            };
            b[pos] ^= 1 << rng.below(8);
        }
        accepted += usize::from(parse(&b, &mut tried));
    }
    // Digits in the header replaced by other digits: sizes, offsets and shapes that disagree.
    let digits: Vec<usize> = (8..header_end)
        .filter(|&k| good[k].is_ascii_digit())
        .collect();
    for _ in 0..2000 {
        let mut b = good.clone();
        for _ in 0..1 + rng.below(3) {
            b[digits[rng.below(digits.len())]] = b'0' + rng.below(10) as u8;
        }
        accepted += usize::from(parse(&b, &mut tried));
    }
    // Random bytes with a plausible length prefix.
    for _ in 0..1000 {
        let n = rng.below(300);
        let mut b: Vec<u8> = (0..n + 8).map(|_| rng.next() as u8).collect();
        b[..8].copy_from_slice(&(n as u64).to_le_bytes());
        accepted += usize::from(parse(&b, &mut tried));
    }
    eprintln!(
        "fuzz_param_file: {tried} corrupted .nam inputs parsed without a panic ({accepted} accepted)"
    );
    assert!(tried > 7000, "{tried}");
}

#[test]
fn huge_declared_maps_are_rejected_before_allocating() {
    let mut tried = 0usize;
    let cfg = r#""__metadata__":{"config":"{\"format\":\"nam-params\",\"version\":1,\"height\":1000000,\"width\":1000000,\"model_sha256\":\"x\"}"}"#;
    // 10^12 × 64 floats (256 TB) claimed by a file of a few hundred bytes.
    let n: u64 = 1_000_000 * 1_000_000 * 64;
    for (shape, end) in [
        ("[1000000,1000000,64]".to_string(), n * 4),
        ("[1000000,1000000,64]".to_string(), 16),
        ("[18446744073709551615,2,64]".to_string(), 16),
        ("[4294967296,4294967296,64]".to_string(), 0),
    ] {
        let h = format!(
            r#"{{{cfg},"params":{{"dtype":"F32","shape":{shape},"data_offsets":[0,{end}]}}}}"#
        );
        assert!(!parse(&raw(&h, 16), &mut tried), "{shape}");
    }
    // Config and tensor disagree, zero-sized maps, zero channels.
    for (h, w, shape) in [
        (0, 0, "[0,0,64]"),
        (2, 2, "[2,2,0]"),
        (2, 3, "[3,2,1]"),
        (1, 1, "[1,1]"),
    ] {
        let cfg = format!(
            r#""__metadata__":{{"config":"{{\"format\":\"nam-params\",\"version\":1,\"height\":{h},\"width\":{w}}}"}}"#
        );
        let len: usize = shape
            .trim_matches(['[', ']'])
            .split(',')
            .map(|d| d.parse::<usize>().unwrap_or(0))
            .product::<usize>()
            * 4;
        let hd = format!(
            r#"{{{cfg},"params":{{"dtype":"F32","shape":{shape},"data_offsets":[0,{len}]}}}}"#
        );
        let ok = parse(&raw(&hd, len), &mut tried);
        if ok {
            // Accepted only when consistent; a zero-channel map is then refused downstream.
            let (m, _) = ParamMap::from_nam_bytes(&raw(&hd, len), "fuzz").expect("ok");
            assert_eq!((m.height, m.width), (h, w), "{shape}");
        }
        assert!(!(h == 0 && ok), "zero-sized map accepted");
        assert!(!(shape == "[3,2,1]" && ok), "transposed shape accepted");
    }
    eprintln!("fuzz_param_file: {tried} hand-written hostile headers");
}
