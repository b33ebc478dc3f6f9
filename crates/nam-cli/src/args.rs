//! Value parsers shared by subcommands (clap `value_parser`s).

use nam::geometry::FOV_RANGE_DEG;

/// Largest accepted coordinate magnitude in `x,y,z` values (surface-frame units: the material
/// spans [−1, 1]²). The networks compute directions in f32, where `|v|²` overflows near 1.8e19
/// and a light at 1e9 is already within 1e-9 rad of a directional light; farther values are
/// an error (use the directional option) instead of a silently wrong direction.
pub const MAX_COORDINATE: f64 = 1e9;

/// Longest part of a rejected argument echoed back in an error message (in characters).
const ECHO_CHARS: usize = 40;

/// `s` for an error message: Debug-quoted (control characters escaped), cut to
/// [`ECHO_CHARS`] characters so a megabyte argument does not become a megabyte message.
fn echo(s: &str) -> String {
    match s.char_indices().nth(ECHO_CHARS) {
        None => format!("{s:?}"),
        Some((cut, _)) => format!("{:?}… ({} bytes)", &s[..cut], s.len()),
    }
}

/// Parses `"x,y,z"` into three finite numbers (spaces around numbers allowed), each with
/// magnitude at most [`MAX_COORDINATE`].
///
/// Errors say what was expected: `expected x,y,z (three comma-separated numbers)`, and reject
/// NaN, infinities (including overflowing literals such as `1e400`) and huge values.
pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 || parts.iter().any(|p| p.is_empty()) {
        return Err(format!(
            "expected x,y,z (three comma-separated numbers), got {}",
            echo(s)
        ));
    }
    let mut out = [0.0; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        let v: f64 = p
            .parse()
            .map_err(|_| format!("expected x,y,z: {} is not a number", echo(p)))?;
        if !v.is_finite() {
            return Err(format!(
                "expected x,y,z: {} is not a finite number",
                echo(p)
            ));
        }
        if v.abs() > MAX_COORDINATE {
            return Err(format!(
                "expected x,y,z: {} is out of range (|value| ≤ {MAX_COORDINATE:e}; use a \
                 directional light or orthographic view for something infinitely far)",
                echo(p)
            ));
        }
        *o = v;
    }
    Ok(out)
}

/// Parses a finite number ≥ 0 (light intensities).
pub fn parse_non_negative(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{} is not a number", echo(s)))?;
    if !v.is_finite() || v < 0.0 {
        return Err(format!("expected a finite number ≥ 0, got {}", echo(s)));
    }
    Ok(v)
}

/// Parses a camera field of view in degrees, within [`FOV_RANGE_DEG`] (5–120, inclusive).
pub fn parse_fov(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{} is not a number of degrees", echo(s)))?;
    if !FOV_RANGE_DEG.contains(&v) {
        return Err(format!(
            "the field of view must be between {} and {} degrees, got {}",
            FOV_RANGE_DEG.start(),
            FOV_RANGE_DEG.end(),
            echo(s)
        ));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec3_accepts_spaces_signs_and_exponents() {
        assert_eq!(parse_vec3("1, -2.5,3e1"), Ok([1.0, -2.5, 30.0]));
    }

    #[test]
    fn vec3_rejects_wrong_arity_nan_inf_and_junk() {
        for bad in ["1,2", "1,2,3,4", "", "1,,3", "nan,0,1", "0,inf,1", "a,b,c"] {
            let e = parse_vec3(bad).err().unwrap_or_default();
            assert!(e.contains("expected x,y,z"), "{bad}: {e}");
        }
    }

    #[test]
    fn intensity_rejects_negative_and_nan() {
        assert_eq!(parse_non_negative("2.5"), Ok(2.5));
        for bad in ["-1", "nan", "inf", "x"] {
            assert!(parse_non_negative(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn fov_accepts_5_to_120_degrees_only() {
        assert_eq!(parse_fov(" 45 "), Ok(45.0));
        assert_eq!(parse_fov("5"), Ok(5.0));
        assert_eq!(parse_fov("120"), Ok(120.0));
        for bad in ["0", "4.99", "120.5", "500", "-28", "nan", "inf"] {
            let e = parse_fov(bad).err().unwrap_or_default();
            assert!(e.contains("between 5 and 120 degrees"), "{bad}: {e}");
        }
        let e = parse_fov("wide").err().unwrap_or_default();
        assert!(e.contains("not a number of degrees"), "{e}");
    }

    #[test]
    fn vec3_rejects_overflowing_huge_and_accepts_boundary_values() {
        for bad in [
            "1e400,0,1",
            "0,-1e309,1",
            "1e10,0,1",
            "0,0,1.000001e9",
            "1,2,-1e300",
        ] {
            let e = parse_vec3(bad).err().unwrap_or_default();
            assert!(e.contains("expected x,y,z"), "{bad}: {e}");
        }
        assert_eq!(parse_vec3("1e9,-1e9,1e4"), Ok([1e9, -1e9, 1e4]));
        // Underflow is not an error: it is 0 (the directional-zero check happens later).
        assert_eq!(parse_vec3("1e-400,-0,5e-324"), Ok([0.0, -0.0, 5e-324]));
    }

    #[test]
    fn vec3_rejects_unicode_lookalikes_and_echoes_long_input_briefly() {
        // Fullwidth digits and comma, U+2212 minus, a zero-width space, an emoji.
        for bad in [
            "１,２,３",
            "1，2，3",
            "\u{2212}1,0,1",
            "1\u{200B},0,1",
            "1,0,🙂",
            "1,0,1\0",
        ] {
            let e = parse_vec3(bad).err().unwrap_or_default();
            assert!(e.contains("expected x,y,z"), "{bad}: {e}");
        }
        // Unicode white space around numbers is trimmed like ASCII spaces.
        assert_eq!(parse_vec3("\u{A0}1,\t2 ,\u{3000}3"), Ok([1.0, 2.0, 3.0]));
        let long = "9".repeat(1 << 20);
        let e = parse_vec3(&long).err().unwrap_or_default();
        assert!(e.len() < 200, "{} bytes", e.len());
        assert!(e.contains("1048576 bytes"), "{e}");
        let e = parse_non_negative(&"é".repeat(1000))
            .err()
            .unwrap_or_default();
        assert!(e.len() < 200 && e.contains("2000 bytes"), "{e}");
    }
}
