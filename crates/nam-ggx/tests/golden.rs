//! Cross-language golden test: the Rust GGX against the torch renderer (`train_py/ggx.py`),
//! through `tests/fixtures/ggx_golden.safetensors` (written by `python -m train_py.golden`,
//! format in docs/FORMAT.md).

use nam_ggx::geometry::{Light, View, directions_at, pixel_position};
use nam_ggx::{DVec3, GgxPoint, Vec3, eval};
use safetensors::{Dtype, SafeTensors};
use std::path::PathBuf;

/// Relative tolerance against torch f64: both sides evaluate the same algebra in f64 and
/// differ only in operation order (e.g. `1−NoH²` vs `(1−NoH)(1+NoH)`) and libm's exp2/pow;
/// measured worst 1.2e-15 over the 191 cases, bounded at 1e-12 for other platforms' libm.
const GOLDEN_REL_TOL_F64: f64 = 1e-12;
/// Absolute floor for values that are (nearly) zero.
const GOLDEN_ABS_TOL_F64: f64 = 1e-12;
/// f32 Rust against torch f64 on the regular cases (roughness ≥ 0.1, cosines ≥ 0.05):
/// measured worst 2.1e-6 (f32 rounding of the inputs and of pow/exp2); bounded at 2e-5.
/// Singular configurations are covered by tests/extreme.rs.
const GOLDEN_REL_TOL_F32: f64 = 2e-5;

fn fixture_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/ggx_golden.safetensors")
}

struct Golden {
    bytes: Vec<u8>,
}

impl Golden {
    fn load() -> Self {
        let path = fixture_path();
        match std::fs::read(&path) {
            Ok(bytes) => Self { bytes },
            Err(e) => panic!(
                "golden fixture {} is missing ({e}); generate it with \
                 `.venv/bin/python -m train_py.golden` from the repository root",
                path.display()
            ),
        }
    }

    fn get(&self, name: &str, shape: &[usize]) -> Vec<f64> {
        let st = SafeTensors::deserialize(&self.bytes)
            .unwrap_or_else(|e| panic!("ggx_golden.safetensors is not valid safetensors: {e}"));
        let t = st
            .tensor(name)
            .unwrap_or_else(|e| panic!("tensor {name} missing from ggx_golden: {e}"));
        assert_eq!(t.dtype(), Dtype::F64, "{name} must be F64 (docs/FORMAT.md)");
        assert_eq!(t.shape(), shape, "{name} shape");
        t.data()
            .chunks_exact(8)
            .map(|c| {
                let mut b = [0u8; 8];
                b.copy_from_slice(c);
                f64::from_le_bytes(b)
            })
            .collect()
    }

    fn n(&self) -> usize {
        let st = SafeTensors::deserialize(&self.bytes)
            .unwrap_or_else(|e| panic!("ggx_golden.safetensors is not valid safetensors: {e}"));
        let t = st
            .tensor("roughness")
            .unwrap_or_else(|e| panic!("tensor roughness missing: {e}"));
        t.shape()[0]
    }
}

fn v3(a: &[f64], k: usize) -> Vec3<f64> {
    Vec3::new(a[3 * k], a[3 * k + 1], a[3 * k + 2])
}

fn arr3(a: &[f64], k: usize) -> [f64; 3] {
    [a[3 * k], a[3 * k + 1], a[3 * k + 2]]
}

/// The fixture's pointwise cases: parameters, (ωi, ωo) pairs, and torch's radiance [N·3].
type Cases = (Vec<GgxPoint<f64>>, Vec<(Vec3<f64>, Vec3<f64>)>, Vec<f64>);

fn cases(g: &Golden) -> Cases {
    let n = g.n();
    let diffuse = g.get("diffuse", &[n, 3]);
    let specular = g.get("specular", &[n, 3]);
    let normal = g.get("normal", &[n, 3]);
    let roughness = g.get("roughness", &[n]);
    let wi = g.get("wi", &[n, 3]);
    let wo = g.get("wo", &[n, 3]);
    let radiance = g.get("radiance", &[n, 3]);
    let points = (0..n)
        .map(|k| GgxPoint {
            diffuse: arr3(&diffuse, k),
            specular: arr3(&specular, k),
            roughness: roughness[k],
            normal: v3(&normal, k),
        })
        .collect();
    let dirs = (0..n).map(|k| (v3(&wi, k), v3(&wo, k))).collect();
    (points, dirs, radiance)
}

#[test]
fn ggx_f64_matches_torch_golden_including_extreme_grid() {
    let g = Golden::load();
    let (points, dirs, radiance) = cases(&g);
    assert!(
        points.len() > 100,
        "fixture should hold the §7 extreme grid"
    );
    let mut worst = 0.0_f64;
    let mut zeros = 0;
    for (k, (p, (wi, wo))) in points.iter().zip(&dirs).enumerate() {
        let got = eval(p, *wi, *wo);
        for c in 0..3 {
            let want = radiance[3 * k + c];
            assert!(got[c].is_finite(), "case {k}: non-finite {got:?}");
            if want == 0.0 {
                // Exact zeros (below the horizon) must stay exact.
                assert_eq!(got[c], 0.0, "case {k} channel {c}: {p:?} {wi:?} {wo:?}");
                zeros += 1;
                continue;
            }
            let err = (got[c] - want).abs();
            worst = worst.max(err / want.abs());
            assert!(
                err <= GOLDEN_REL_TOL_F64 * want.abs() + GOLDEN_ABS_TOL_F64,
                "case {k} channel {c}: rust {} torch {want} (rel {:e})\n{p:?}\nwi {wi:?} wo {wo:?}",
                got[c],
                err / want.abs()
            );
        }
    }
    assert!(
        zeros > 0,
        "the extreme grid should contain below-horizon cases"
    );
    println!("worst f64 relative difference to torch: {worst:e}");
}

#[test]
fn ggx_f32_stays_within_tolerance_of_torch_golden_on_regular_cases() {
    let g = Golden::load();
    let (points, dirs, radiance) = cases(&g);
    let mut checked = 0;
    let mut worst = 0.0_f64;
    for (k, (p, (wi, wo))) in points.iter().zip(&dirs).enumerate() {
        // Regular = roughness ≥ 0.1 and both cosines ≥ 0.05: away from the α clamp and from
        // grazing, where f32 rounding of the directions themselves dominates.
        let (nol, nov) = (p.normal.dot(*wi), p.normal.dot(*wo));
        if p.roughness < 0.1 || nol < 0.05 || nov < 0.05 {
            continue;
        }
        let got = eval(&p.cast::<f32>(), wi.cast(), wo.cast());
        for c in 0..3 {
            let want = radiance[3 * k + c];
            let err = (f64::from(got[c]) - want).abs() / want.abs().max(1e-6);
            worst = worst.max(err);
            assert!(
                err <= GOLDEN_REL_TOL_F32,
                "case {k} channel {c}: rel {err:e}"
            );
        }
        checked += 1;
    }
    assert!(checked > 20, "only {checked} regular cases");
    println!("worst f32 relative difference to torch on {checked} cases: {worst:e}");
}

#[test]
fn pixel_geometry_matches_torch_golden_on_5x7_image() {
    let g = Golden::load();
    let (h, w) = (5, 7);
    let light = g.get("geom_light", &[3]);
    let view = g.get("geom_view", &[3]);
    let light = Light::Point(DVec3::new(light[0], light[1], light[2]));
    let view = View::Point(DVec3::new(view[0], view[1], view[2]));
    let gwi = g.get("geom_wi", &[h, w, 3]);
    let gwo = g.get("geom_wo", &[h, w, 3]);
    let gwh = g.get("geom_wh", &[h, w, 3]);
    /// Normalising the same f64 vectors in a different operation order: a few ulps.
    const GEOM_TOL: f64 = 1e-14;
    for i in 0..h {
        for j in 0..w {
            let k = i * w + j;
            let d = directions_at(&light, &view, pixel_position(i, j, h, w))
                .unwrap_or_else(|| panic!("degenerate pixel {i},{j}"));
            for (name, got, want) in [
                ("wi", d.wi, v3(&gwi, k)),
                ("wo", d.wo, v3(&gwo, k)),
                ("wh", d.wh, v3(&gwh, k)),
            ] {
                let err = (got - want).length();
                assert!(err < GEOM_TOL, "{name} at ({i},{j}): {got:?} vs {want:?}");
            }
        }
    }
}
