//! Where a scenario value came from, for error messages: the file, its
//! text (for line numbers) and the paths set by `--set`; with the range
//! checks every validation section shares.

use glam::DVec3;

use super::ScenarioError;
use super::locate;
use super::raw::RawInt;

/// What errors need to know about their origin.
pub(crate) struct Ctx<'a> {
    pub file: &'a str,
    pub text: &'a str,
    /// Display paths set by `--set`.
    pub overridden: &'a [String],
}

type R<T> = Result<T, ScenarioError>;

fn under(path: &str, prefix: &str) -> bool {
    path == prefix
        || path
            .strip_prefix(prefix)
            .is_some_and(|rest| rest.starts_with('.') || rest.starts_with('['))
}

impl Ctx<'_> {
    /// A field error; the location is looked up in the text unless the field
    /// was set by `--set`.
    pub fn err(&self, path: impl Into<String>, message: impl Into<String>) -> ScenarioError {
        self.err_impl(path.into(), message.into(), false)
    }

    fn err_impl(&self, path: String, message: String, at_key: bool) -> ScenarioError {
        let mut message = message;
        let location = if self.overridden.iter().any(|o| under(&path, o)) {
            message.push_str(" (value from --set)");
            None
        } else {
            locate::locate(self.text, &path, at_key)
        };
        ScenarioError::Field {
            file: self.file.to_string(),
            path,
            message,
            location,
        }
    }

    pub fn serde_error(&self, e: serde_path_to_error::Error<toml::de::Error>) -> ScenarioError {
        let mut path = e.path().to_string();
        if path == "." {
            path.clear();
        }
        let msg = e.inner().message().trim().to_string();
        let join = |p: &str, k: &str| {
            if p.is_empty() {
                k.to_string()
            } else {
                format!("{p}.{k}")
            }
        };
        let quoted = |m: &str| m.split('`').nth(1).map(str::to_string);
        let unknown_key = msg.starts_with("unknown field ");
        let (path, message) = if let Some(rest) = msg.strip_prefix("missing field ") {
            match quoted(rest) {
                Some(k) => (join(&path, &k), "required key is missing".to_string()),
                None => (path, msg),
            }
        } else if let Some(rest) = msg.strip_prefix("unknown field ") {
            let message = format!("unknown key {rest}");
            match quoted(rest) {
                Some(k) if !path.ends_with(&k) => (join(&path, &k), message),
                _ => (path, message),
            }
        } else if let Some(rest) = msg.strip_prefix("unknown variant ") {
            (path, format!("invalid value {rest}"))
        } else {
            (path, msg)
        };
        let path = if path.is_empty() {
            "(top level)".to_string()
        } else {
            path
        };
        self.err_impl(path, message, unknown_key)
    }

    pub(super) fn positive(&self, path: &str, v: f64) -> R<f64> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(path, format!("must be > 0 and finite, got {v:?}")))
        }
    }

    pub(super) fn non_negative(&self, path: &str, v: f64) -> R<f64> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(self.err(path, format!("must be >= 0 and finite, got {v:?}")))
        }
    }

    pub(super) fn closed(&self, path: &str, v: f64, lo: f64, hi: f64) -> R<f64> {
        if v >= lo && v <= hi {
            Ok(v)
        } else {
            Err(self.err(path, format!("must be in [{lo:?}, {hi:?}], got {v:?}")))
        }
    }

    pub(super) fn vec3(&self, path: &str, a: [f64; 3]) -> R<DVec3> {
        for (i, x) in a.iter().enumerate() {
            if !x.is_finite() {
                return Err(self.err(format!("{path}[{i}]"), format!("must be finite, got {x:?}")));
            }
        }
        Ok(DVec3::from_array(a))
    }

    pub(super) fn uint(&self, path: &str, v: &RawInt) -> R<u64> {
        match v {
            toml::Value::Integer(n) if *n >= 0 => Ok(*n as u64),
            other => Err(self.err(path, format!("must be a non-negative integer, got {other}"))),
        }
    }
}
