//! Capture and relighting geometry (DESIGN §3).
//!
//! The material lies on z = 0 and spans [-1, 1]² in x, y. Pixel (row i, col j)
//! of an H×W image is at `x = 2(j+0.5)/W − 1`, `y = −2(i+0.5)/H + 1`. All
//! directions are unit vectors in the surface frame (z up).

/// Capture distance `d = 1/tan(14°)` (FOV 28°), in units of the half-width of the material.
pub const CAPTURE_DISTANCE: f32 = 4.010_781;

/// `|ωi + ωo|²` below which the half vector is undefined; [`half_vector`] then
/// returns the surface normal (ωi and ωo point in opposite directions).
pub const HALF_VECTOR_GUARD: f32 = 1e-12;

/// Surface-frame position `(x, y, 0)` of the centre of pixel (row, col) in an H×W image.
pub fn pixel_position(row: usize, col: usize, height: usize, width: usize) -> [f32; 3] {
    let x = 2.0 * (col as f32 + 0.5) / width as f32 - 1.0;
    let y = -2.0 * (row as f32 + 0.5) / height as f32 + 1.0;
    [x, y, 0.0]
}

/// `normalize(to − from)`; the zero vector maps to the surface normal.
pub fn direction(from: [f32; 3], to: [f32; 3]) -> [f32; 3] {
    let d = [to[0] - from[0], to[1] - from[1], to[2] - from[2]];
    normalize_or_normal(d)
}

/// `normalize(ωi + ωo)`, or the normal `(0, 0, 1)` when `|ωi + ωo|² < HALF_VECTOR_GUARD`.
pub fn half_vector(wi: [f32; 3], wo: [f32; 3]) -> [f32; 3] {
    let s = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
    normalize_or_normal(s)
}

fn normalize_or_normal(v: [f32; 3]) -> [f32; 3] {
    let mut n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let mut v = v;
    if n2.is_infinite() && v.iter().all(|x| x.is_finite()) {
        // |v|² overflowed (a light at ~1e20): rescale by the largest component first; the
        // direction is the same and the usual path below stays bit-identical to torch.
        let m = v.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        v = v.map(|x| x / m);
        n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    }
    if n2.is_nan() || n2 < HALF_VECTOR_GUARD || !n2.is_finite() {
        return [0.0, 0.0, 1.0];
    }
    // Divide (not multiply by a reciprocal): correctly rounded like torch's
    // `s / norm`, which matters because the encoding scales ωh by up to 2^15·π.
    let n = n2.sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// Per-pixel `(ωi, ωo)` for a point light at `light` and a pinhole view at `view`
/// (both in surface-frame units), row-major over the H×W image.
pub fn pixel_directions(
    height: usize,
    width: usize,
    light: [f32; 3],
    view: [f32; 3],
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut wi = Vec::with_capacity(height * width);
    let mut wo = Vec::with_capacity(height * width);
    for i in 0..height {
        for j in 0..width {
            let p = pixel_position(i, j, height, width);
            wi.push(direction(p, light));
            wo.push(direction(p, view));
        }
    }
    (wi, wo)
}

/// Channel 3 of the network input: z of the capture half vector at pixel
/// (row, col), `d / sqrt(x² + y² + d²)` (light and camera co-located at (0, 0, d)).
pub fn capture_half_z(row: usize, col: usize, height: usize, width: usize) -> f32 {
    let [x, y, _] = pixel_position(row, col, height, width);
    let d = CAPTURE_DISTANCE;
    d / (x * x + y * y + d * d).sqrt()
}

#[cfg(test)]
mod overflow_tests {
    use super::direction;

    #[test]
    fn far_lights_keep_their_direction_when_the_squared_length_overflows() {
        let d = direction([0.0; 3], [1e20, 0.0, 1.0]);
        assert!(
            (d[0] - 1.0).abs() < 1e-6 && d[2] > 0.0 && d[2] < 1e-6,
            "{d:?}"
        );
        let d = direction([0.0; 3], [3e38, -3e38, 3e38]);
        let r = 1.0 / 3f32.sqrt();
        assert!((d[0] - r).abs() < 1e-6 && (d[1] + r).abs() < 1e-6, "{d:?}");
    }
}
