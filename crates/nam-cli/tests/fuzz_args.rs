//! Hostile CLI vectors (issue #8.3): `--light`/`--view`/`--intensity` values that are NaN,
//! infinite, overflowing, huge, malformed (`1,,2`), unicode look-alikes or megabytes long must
//! be a clear error, never a panic; accepted values must be exactly what was written.
//! A bounded corpus run: fixed seed, fixed case count (well under a second in debug).

// The binary's value parsers, compiled into this test (nam-cli has no library target).
#[path = "../src/args.rs"]
mod args;

use args::{MAX_COORDINATE, parse_non_negative, parse_vec3};
use nam_weights::SplitMix64;
use std::process::Command;

/// Tokens the random strings are built from: number pieces, separators, words the float
/// parser knows, and unicode look-alikes.
const TOKENS: &[&str] = &[
    "0",
    "1",
    "2",
    "9",
    "42",
    ".",
    ",",
    ",",
    ",",
    "-",
    "+",
    "e",
    "E",
    "e-",
    "e+",
    " ",
    "\t",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "infinity",
    "1e308",
    "1e309",
    "1e400",
    "1e-400",
    "5e-324",
    "1e9",
    "1e10",
    "999999999",
    "0x10",
    "1_0",
    "\u{A0}",
    "\u{2212}",
    "\u{FF0C}",
    "\u{FF11}",
    "\u{200B}",
    "é",
    "🙂",
    "\0",
    "\n",
    ";",
    ":",
    "(",
    ")",
    "[",
    "]",
];

fn random_string(rng: &mut SplitMix64) -> String {
    let n = rng.below(12);
    (0..n).map(|_| TOKENS[rng.below(TOKENS.len())]).collect()
}

/// The oracle: what `parse_vec3` must return, from std's parser and the documented rules.
fn expected_vec3(s: &str) -> Option<[f64; 3]> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return None;
    }
    let mut out = [0.0; 3];
    for (o, p) in out.iter_mut().zip(parts) {
        let v: f64 = p.parse().ok()?;
        if !v.is_finite() || v.abs() > MAX_COORDINATE {
            return None;
        }
        *o = v;
    }
    Some(out)
}

fn check_vec3(s: &str, tried: &mut usize) -> Option<[f64; 3]> {
    *tried += 1;
    let got = std::panic::catch_unwind(|| parse_vec3(s))
        .unwrap_or_else(|_| panic!("parse_vec3 panicked on {s:?}"));
    match (&got, expected_vec3(s)) {
        (Ok(v), Some(w)) => {
            assert_eq!(v.map(f64::to_bits), w.map(f64::to_bits), "{s:?}");
            // Display of f64 round-trips: what was accepted is exactly what was written.
            let again = format!("{},{},{}", v[0], v[1], v[2]);
            assert_eq!(
                parse_vec3(&again).map(|a| a.map(f64::to_bits)),
                Ok(v.map(f64::to_bits))
            );
        }
        (Err(e), None) => {
            assert!(e.contains("expected x,y,z"), "{s:?}: {e}");
            assert!(e.len() < 400, "{s:?}: {}-byte message", e.len());
        }
        (got, want) => panic!("{s:?}: got {got:?}, oracle {want:?}"),
    }
    got.ok()
}

fn check_non_negative(s: &str, tried: &mut usize) {
    *tried += 1;
    let got = std::panic::catch_unwind(|| parse_non_negative(s))
        .unwrap_or_else(|_| panic!("parse_non_negative panicked on {s:?}"));
    let want = s
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0);
    match (got, want) {
        (Ok(v), Some(w)) => assert_eq!(v.to_bits(), w.to_bits(), "{s:?}"),
        (Err(e), None) => assert!(e.len() < 400, "{s:?}: {}-byte message", e.len()),
        (got, want) => panic!("{s:?}: got {got:?}, oracle {want:?}"),
    }
}

#[test]
fn random_and_hostile_vectors_match_the_oracle_and_never_panic() {
    let mut rng = SplitMix64(0xC0FF_EE00_D15E_A5E5);
    let mut tried = 0usize;
    let mut accepted = 0usize;

    // 1. Hand-written hostile values.
    let hostile = [
        "",
        ",",
        ",,",
        "1,,2",
        ",1,2",
        "1,2,",
        "1,2,3,",
        "1 2 3",
        "1;2;3",
        "(1,2,3)",
        "[1,2,3]",
        "nan,0,1",
        "NaN,NaN,NaN",
        "inf,0,1",
        "0,-inf,1",
        "infinity,0,0",
        "1e309,0,1",
        "1e308,1e308,1e308",
        "-1e308,0,1",
        "1e9,1e9,1e9",
        "1e9,0,1.0000001e9",
        "0x10,0,1",
        "1_000,0,1",
        "１,２,３",
        "1，2，3",
        "\u{2212}1,0,1",
        "1\u{200B},0,1",
        "1,0,🙂",
        "1,0,1\0",
        "\u{A0}1,2,3\u{3000}",
        "\t1 , 2 ,\n3 ",
        "+1,-0,.5",
        "5.,1e-400,-5e-324",
        "--1,0,1",
    ];
    for s in hostile {
        accepted += usize::from(check_vec3(s, &mut tried).is_some());
        check_non_negative(s, &mut tried);
    }
    // A megabyte argument: an error, with a short message.
    let long = format!("{},0,1", "1".repeat(1 << 20));
    assert!(check_vec3(&long, &mut tried).is_none());
    check_non_negative(&"9".repeat(1 << 20), &mut tried);

    // 2. Random token strings.
    const RANDOM: usize = 20_000;
    for _ in 0..RANDOM {
        let s = random_string(&mut rng);
        accepted += usize::from(check_vec3(&s, &mut tried).is_some());
        check_non_negative(&s, &mut tried);
    }
    // 3. Random f64 bit patterns (NaN payloads, infinities, denormals, huge) in three formats.
    const BITS: usize = 5_000;
    for _ in 0..BITS {
        let v: [f64; 3] = [0; 3].map(|_| f64::from_bits(rng.next()));
        for s in [
            format!("{},{},{}", v[0], v[1], v[2]),
            format!("{:e}, {:e} ,{:e}", v[0], v[1], v[2]),
            format!(" {:?},{:?},{:?} ", v[0], v[1], v[2]),
        ] {
            let ok = check_vec3(&s, &mut tried);
            let valid = v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE);
            assert_eq!(ok.is_some(), valid, "{s}");
            accepted += usize::from(ok.is_some());
        }
        check_non_negative(&format!("{}", v[0]), &mut tried);
    }
    // 4. Random in-range values: always accepted, bit-exact.
    for _ in 0..BITS {
        let v = [0; 3].map(|_| {
            let unit = (rng.next() >> 11) as f64 / (1u64 << 53) as f64;
            (unit * 2.0 - 1.0) * 10f64.powi(rng.below(19) as i32 - 9)
        });
        let got = check_vec3(&format!("{},{},{}", v[0], v[1], v[2]), &mut tried);
        assert_eq!(got.map(|a| a.map(f64::to_bits)), Some(v.map(f64::to_bits)));
        accepted += 1;
    }
    eprintln!(
        "fuzz_args: {tried} argument strings parsed without a panic ({accepted} vectors accepted)"
    );
    assert!(tried > 50_000, "{tried}");
}

#[test]
fn the_binary_reports_bad_vectors_as_usage_errors_not_panics() {
    let exe = env!("CARGO_BIN_EXE_nam-cli");
    let dir = std::env::temp_dir();
    let out = dir.join("nam_fuzz_args_never_written.png");
    let mut tried = 0usize;
    for bad in [
        "nan,0,1",
        "1,,2",
        "1e400,0,1",
        "1e20,0,1",
        "１,２,３",
        "inf,inf,inf",
        "",
    ] {
        for flag in ["--light", "--view"] {
            let (light, view) = if flag == "--light" {
                (bad, "0,0,4")
            } else {
                ("0,0,4", bad)
            };
            let o = Command::new(exe)
                .args([
                    "render-ggx",
                    "no_such_maps.png",
                    "--light",
                    light,
                    "--view",
                    view,
                    "-o",
                ])
                .arg(&out)
                .output()
                .expect("run nam-cli");
            tried += 1;
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{flag} {bad:?}: {err}");
            assert!(err.contains("expected x,y,z"), "{flag} {bad:?}: {err}");
            assert!(!err.contains("panicked"), "{flag} {bad:?}: {err}");
        }
    }
    for bad in ["-1", "nan", "inf", "1e400", "x"] {
        let o = Command::new(exe)
            .args([
                "render-ggx",
                "m.png",
                "--light",
                "0,0,4",
                "--view",
                "0,0,4",
                "--intensity",
                bad,
            ])
            .arg("-o")
            .arg(&out)
            .output()
            .expect("run nam-cli");
        tried += 1;
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "--intensity {bad:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(!out.exists());
    eprintln!("fuzz_args: {tried} command lines rejected with a usage error");
}
