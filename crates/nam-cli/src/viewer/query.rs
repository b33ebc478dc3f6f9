//! A request URL split into its path and query parameters, with typed getters whose errors
//! are the messages a 400 response carries. Values are numbers, comma lists and plain words:
//! percent-escapes of printable ASCII are decoded (browsers send `,` as `%2C`), others refused.

use crate::args::{parse_non_negative, parse_vec3};

/// `path?key=value&…` of one request.
#[derive(Debug)]
pub struct Query<'a> {
    /// The path, `/` first.
    pub path: &'a str,
    pairs: Vec<(&'a str, &'a str)>,
}

impl<'a> Query<'a> {
    /// Splits a request target; a repeated key keeps its first value.
    pub fn parse(url: &'a str) -> Self {
        let (path, query) = url.split_once('?').unwrap_or((url, ""));
        let pairs = query
            .split('&')
            .filter(|p| !p.is_empty())
            .map(|p| p.split_once('=').unwrap_or((p, "")))
            .collect();
        Self { path, pairs }
    }

    /// The raw value of `key`, if present.
    pub fn get(&self, key: &str) -> Option<&'a str> {
        self.pairs.iter().find(|(k, _)| *k == key).map(|(_, v)| *v)
    }

    /// `key=x,y,z`, required.
    pub fn vec3(&self, key: &str) -> Result<[f64; 3], String> {
        let v = self
            .get(key)
            .ok_or_else(|| format!("missing {key}=x,y,z"))?;
        parse_vec3(&plain(v)?).map_err(|e| format!("{key}: {e}"))
    }

    /// `key=v` (finite, ≥ 0), or `default` when absent.
    pub fn non_negative(&self, key: &str, default: f64) -> Result<f64, String> {
        match self.get(key) {
            None => Ok(default),
            Some(v) => parse_non_negative(&plain(v)?).map_err(|e| format!("{key}: {e}")),
        }
    }

    /// `key=0|1|true|false`, `false` when absent.
    pub fn flag(&self, key: &str) -> Result<bool, String> {
        match self.get(key) {
            None | Some("0" | "false") => Ok(false),
            Some("1" | "true") => Ok(true),
            Some(v) => Err(format!("{key} must be 0 or 1, got {:?}", truncate(v))),
        }
    }

    /// `key` ∈ `choices` (the first when absent).
    pub fn choice(&self, key: &str, choices: &[&'static str]) -> Result<&'static str, String> {
        match self.get(key) {
            None => Ok(choices[0]),
            Some(v) => {
                choices.iter().find(|c| **c == v).copied().ok_or_else(|| {
                    format!("{key} must be one of {choices:?}, got {:?}", truncate(v))
                })
            }
        }
    }
}

/// The value with `%XX` escapes of printable ASCII decoded; any other escape is an error.
fn plain(v: &str) -> Result<String, String> {
    let bad = || format!("bad percent-escape in {:?}", truncate(v));
    let mut out = String::with_capacity(v.len());
    let mut rest = v;
    while let Some(k) = rest.find('%') {
        out.push_str(&rest[..k]);
        let hex = rest.get(k + 1..k + 3).ok_or_else(bad)?;
        let c = u8::from_str_radix(hex, 16).map_err(|_| bad())?;
        if !(0x20..0x7f).contains(&c) {
            return Err(bad());
        }
        out.push(char::from(c));
        rest = &rest[k + 3..];
    }
    out.push_str(rest);
    Ok(out)
}

/// At most 40 characters of a value, for error messages.
fn truncate(v: &str) -> String {
    v.chars().take(40).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_values_and_explains_bad_ones() {
        let q = Query::parse(
            "/api/frame?t=ab&light=1,2,3&ortho=1&intensity=2.5&bad=1%2C2%&esc=1%2C2%2c3&z=1%00,2,3",
        );
        assert_eq!(q.path, "/api/frame");
        assert_eq!(q.get("t"), Some("ab"));
        assert_eq!(q.vec3("light"), Ok([1.0, 2.0, 3.0]));
        assert_eq!(q.flag("ortho"), Ok(true));
        assert_eq!(q.flag("falloff"), Ok(false));
        assert_eq!(q.non_negative("intensity", 1.0), Ok(2.5));
        assert_eq!(q.non_negative("gain", 1.0), Ok(1.0));
        assert!(q.vec3("bad").unwrap_err().contains("percent"));
        assert_eq!(q.vec3("esc"), Ok([1.0, 2.0, 3.0]));
        assert!(q.vec3("z").unwrap_err().contains("percent"));
        assert!(q.vec3("view").unwrap_err().contains("missing view"));
        assert_eq!(q.choice("fmt", &["rgb8", "f32"]), Ok("rgb8"));
        let q = Query::parse("/x?fmt=gif&intensity=-1&ortho=yes&light=1,2");
        assert!(q.choice("fmt", &["rgb8", "f32"]).is_err());
        assert!(q.non_negative("intensity", 1.0).is_err());
        assert!(q.flag("ortho").is_err());
        assert!(q.vec3("light").is_err());
    }
}
