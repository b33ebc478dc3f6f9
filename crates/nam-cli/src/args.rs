//! Value parsers shared by subcommands (clap `value_parser`s).

/// Parses `"x,y,z"` into three finite numbers (spaces around numbers allowed).
///
/// Errors say what was expected: `expected x,y,z (three comma-separated numbers)`, and reject
/// NaN and infinities.
pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 || parts.iter().any(|p| p.is_empty()) {
        return Err(format!(
            "expected x,y,z (three comma-separated numbers), got {s:?}"
        ));
    }
    let mut out = [0.0; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        let v: f64 = p
            .parse()
            .map_err(|_| format!("expected x,y,z: {p:?} is not a number"))?;
        if !v.is_finite() {
            return Err(format!("expected x,y,z: {p:?} is not a finite number"));
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
        .map_err(|_| format!("{s:?} is not a number"))?;
    if !v.is_finite() || v < 0.0 {
        return Err(format!("expected a finite number ≥ 0, got {s:?}"));
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
}
