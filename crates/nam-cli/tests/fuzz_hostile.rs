//! A seeded fuzz of whole `nam-cli relight` runs (issue 19): extreme scene values (class 1),
//! outputs that collide with inputs or each other (class 4), runs that fail after writing
//! (class 5) and files that must not be read whole (class 6). Every run must either succeed
//! with finite output files, or fail cleanly: no panic, none of its outputs left, no
//! temporary files, the input untouched. The counts per class are printed.

mod common;

use common::{root, run, s, stderr, tmp};
use nam_weights::SplitMix64;
use std::path::{Path, PathBuf};

/// Invocations per class (each runs the binary; ~0.1 s apiece on the 16² photo).
const CASES_PER_CLASS: usize = 24;

/// Values that stress the scene checks: tiny, huge, at and beyond the limits.
const HEIGHTS: &[&str] = &[
    "3", "1e-46", "1e-38", "1.2e-38", "1e-19", "1e-3", "1e30", "3e38", "1e39", "0.5",
];
const INTENSITIES: &[&str] = &["1", "0", "1e6", "1000001", "1e39", "3.4e38", "1e-300"];

fn photo(dir: &Path) -> PathBuf {
    let path = dir.join("photo.png");
    image::open(root().join("assets/example_photo.png"))
        .unwrap_or_else(|e| panic!("{e}"))
        .resize_exact(16, 16, image::imageops::FilterType::Triangle)
        .save(&path)
        .unwrap_or_else(|e| panic!("{e}"));
    path
}

/// The names in `dir`.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Runs `args` in `dir` (whose files before the run are `before`) and checks the contract;
/// returns whether it succeeded.
fn check_run(
    args: &[String],
    dir: &Path,
    before: &[String],
    input: &Path,
    input_bytes: &[u8],
) -> bool {
    let argv: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = run(&argv);
    let err = stderr(&o);
    assert!(!err.contains("panicked"), "{argv:?}: {err}");
    assert_eq!(
        std::fs::read(input).unwrap_or_default(),
        input_bytes,
        "{argv:?} changed its input"
    );
    let after = listing(dir);
    assert!(
        !after.iter().any(|n| n.ends_with(".tmp")),
        "{argv:?} left temporary files: {after:?}"
    );
    if o.status.success() {
        for name in after
            .iter()
            .filter(|n| !before.contains(n) && n.ends_with(".exr"))
        {
            let (img, _) =
                nam_ggx::imageio::read_rgb(&dir.join(name)).unwrap_or_else(|e| panic!("{e}"));
            assert!(
                img.data().iter().all(|v| v.is_finite()),
                "{argv:?}: {name} has non-finite values"
            );
        }
    } else {
        assert_eq!(after, before, "{argv:?} failed ({err}) but left files");
    }
    o.status.success()
}

fn relight_args(input: &Path, extra: &[String]) -> Vec<String> {
    let mut v: Vec<String> = ["relight", s(input), "--backend", "cpu"]
        .map(String::from)
        .to_vec();
    v.extend_from_slice(extra);
    v
}

#[test]
fn seeded_hostile_runs_succeed_finite_or_fail_leaving_nothing() {
    let dir = tmp();
    let d = dir.path();
    let input = photo(d);
    let input_bytes = std::fs::read(&input).unwrap_or_else(|e| panic!("{e}"));
    let mut rng = SplitMix64(0x1915_0000_F00D);
    let mut counts = [(0usize, 0usize); 4]; // (tried, succeeded) per class
    let out = |name: &str| d.join(name).to_string_lossy().into_owned();
    for _ in 0..CASES_PER_CLASS {
        // Class 1: extreme heights, intensities and falloff.
        let before = listing(d);
        let (x, z) = (
            rng.pick(&["0", "0.03125", "-0.9", "1e30"]),
            rng.pick(HEIGHTS),
        );
        let mut extra = vec![
            "--light".into(),
            format!("{x},0.03125,{z}"),
            "--intensity".into(),
            rng.pick(INTENSITIES).to_string(),
        ];
        if rng.below(2) == 0 {
            extra.push("--falloff".into());
        }
        if rng.below(3) == 0 {
            extra.extend(["--view".into(), format!("0,0,{}", rng.pick(HEIGHTS))]);
        }
        extra.extend(["-o".into(), out("c1.exr")]);
        let ok = check_run(
            &relight_args(&input, &extra),
            d,
            &before,
            &input,
            &input_bytes,
        );
        counts[0] = (counts[0].0 + 1, counts[0].1 + usize::from(ok));
        let _ = std::fs::remove_file(d.join("c1.exr"));

        // Class 4: outputs named like the input or like each other.
        let before = listing(d);
        let names = [
            s(&input).to_string(),
            format!("{}/./photo.png", d.display()),
            out("f_001.png"),
            out("f.png"),
            out("sheet.png"),
        ];
        let extra = vec![
            "--light".into(),
            "orbit:3".into(),
            "-o".into(),
            rng.pick(&names).clone(),
            "--sheet".into(),
            rng.pick(&names).clone(),
        ];
        let ok = check_run(
            &relight_args(&input, &extra),
            d,
            &before,
            &input,
            &input_bytes,
        );
        counts[1] = (counts[1].0 + 1, counts[1].1 + usize::from(ok));
        for name in listing(d).iter().filter(|n| !before.contains(n)) {
            let _ = std::fs::remove_file(d.join(name));
        }

        // Class 5: a sweep whose last output cannot be moved into place (over-long name).
        let before = listing(d);
        let n = 1 + rng.below(4);
        let long = rng.below(2) == 0;
        let gif = if long {
            format!("{}.gif", "g".repeat(300))
        } else {
            "g.gif".into()
        };
        let extra = vec![
            "--light".into(),
            format!("orbit:{n}"),
            "-o".into(),
            out("s.png"),
            "--sheet".into(),
            out("ss.png"),
            "--gif".into(),
            out(&gif),
        ];
        let ok = check_run(
            &relight_args(&input, &extra),
            d,
            &before,
            &input,
            &input_bytes,
        );
        assert_eq!(ok, !long, "class 5 with {gif}");
        counts[2] = (counts[2].0 + 1, counts[2].1 + usize::from(ok));
        for name in listing(d).iter().filter(|n| !before.contains(n)) {
            let _ = std::fs::remove_file(d.join(name));
        }

        // Class 6: inputs that must not be read whole.
        let before = listing(d);
        let kind = rng.below(3);
        let bad = d.join(["big.png", "big.safetensors", "dev.nam"][kind]);
        match kind {
            0 => std::fs::File::create(&bad)
                .and_then(|f| {
                    f.set_len(
                        nam_ggx::imageio::MAX_IMAGE_FILE_BYTES + 1 + rng.below(1 << 20) as u64,
                    )
                })
                .unwrap_or_else(|e| panic!("{e}")),
            1 => std::fs::File::create(&bad)
                .and_then(|f| f.set_len(nam::MAX_MODEL_FILE_BYTES + 1 + rng.below(1 << 20) as u64))
                .unwrap_or_else(|e| panic!("{e}")),
            _ => {
                #[cfg(unix)]
                std::os::unix::fs::symlink("/dev/zero", &bad).unwrap_or_else(|e| panic!("{e}"));
            }
        }
        let before_with_bad = listing(d);
        let extra = vec!["--light".into(), "1,1,3".into(), "-o".into(), out("c6.png")];
        let args = match kind {
            1 => relight_args(
                &input,
                &[&["--model".to_string(), s(&bad).into()][..], &extra].concat(),
            ),
            _ => relight_args(&bad, &extra),
        };
        let ok = check_run(&args, d, &before_with_bad, &input, &input_bytes);
        assert!(
            !ok || (kind == 2 && !cfg!(unix)),
            "class 6 kind {kind} succeeded"
        );
        counts[3] = (counts[3].0 + 1, counts[3].1 + usize::from(ok));
        let _ = std::fs::remove_file(&bad);
        assert_eq!(listing(d), before);
    }
    for (class, (tried, succeeded)) in [1, 4, 5, 6].iter().zip(counts) {
        println!(
            "class {class}: {tried} runs, {succeeded} succeeded with finite outputs, {} refused cleanly",
            tried - succeeded
        );
    }
    // Both outcomes occur where the corpus mixes valid and invalid runs.
    assert!(
        counts[0].1 > 0 && counts[0].1 < counts[0].0,
        "class 1 {counts:?}"
    );
    assert!(counts[1].1 < counts[1].0, "class 4 {counts:?}");
}
