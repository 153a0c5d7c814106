//! `--set KEY=VALUE` overrides applied to the parsed TOML tree.

use toml::{Table, Value};

/// Applies one `KEY=VALUE` override; returns the field path in display form
/// (`particles[0].count`) or a message.
///
/// KEY is a dotted path; a segment that addresses an array must be an index
/// of an existing element. Missing tables along the path and a missing leaf
/// key are created. VALUE is parsed as a TOML value (number, bool, string in
/// quotes, array, inline table) and otherwise taken as a plain string.
pub(super) fn apply(root: &mut Table, arg: &str) -> Result<String, String> {
    let (key, value) = arg
        .split_once('=')
        .ok_or_else(|| "expected KEY=VALUE (e.g. time.t_end=0.5)".to_string())?;
    let segments = split_key(key)?;
    let value = parse_value(value.trim());
    let mut display = String::new();
    set_in_table(root, &segments, value, &mut display)?;
    Ok(display)
}

/// The display path of an override argument, if its key is well formed.
pub(super) fn display_path(arg: &str) -> Option<String> {
    let (key, _) = arg.split_once('=')?;
    let segments = split_key(key).ok()?;
    let mut out = String::new();
    for s in segments {
        push_segment(&mut out, s);
    }
    Some(out)
}

fn split_key(key: &str) -> Result<Vec<&str>, String> {
    let key = key.trim();
    if key.is_empty() {
        return Err("empty key; expected KEY=VALUE (e.g. time.t_end=0.5)".to_string());
    }
    let segments: Vec<&str> = key.split('.').map(str::trim).collect();
    if segments.iter().any(|s| s.is_empty()) {
        return Err(format!("key `{key}` has an empty segment"));
    }
    Ok(segments)
}

fn is_index(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())
}

fn push_segment(out: &mut String, seg: &str) {
    if is_index(seg) {
        out.push('[');
        out.push_str(seg);
        out.push(']');
    } else {
        if !out.is_empty() {
            out.push('.');
        }
        out.push_str(seg);
    }
}

fn parse_value(text: &str) -> Value {
    let doc = format!("v = {text}");
    match doc.parse::<Table>() {
        Ok(mut t) if t.len() == 1 => t
            .remove("v")
            .unwrap_or_else(|| Value::String(text.to_string())),
        _ => Value::String(text.to_string()),
    }
}

fn set_in_table(
    table: &mut Table,
    segments: &[&str],
    value: Value,
    display: &mut String,
) -> Result<(), String> {
    let Some((seg, rest)) = segments.split_first() else {
        return Err("empty key".to_string());
    };
    push_segment(display, seg);
    if rest.is_empty() {
        table.insert(seg.to_string(), value);
        return Ok(());
    }
    if !table.contains_key(*seg) {
        if is_index(rest[0]) {
            return Err(format!(
                "`{display}` does not exist, so it cannot be indexed with {}",
                rest[0]
            ));
        }
        table.insert(seg.to_string(), Value::Table(Table::new()));
    }
    match table.get_mut(*seg) {
        Some(child) => set_in_value(child, rest, value, display),
        None => Err(format!("`{display}` does not exist")),
    }
}

fn set_in_value(
    node: &mut Value,
    segments: &[&str],
    value: Value,
    display: &mut String,
) -> Result<(), String> {
    match node {
        Value::Table(t) => set_in_table(t, segments, value, display),
        Value::Array(a) => {
            let Some((seg, rest)) = segments.split_first() else {
                return Err("empty key".to_string());
            };
            if !is_index(seg) {
                return Err(format!(
                    "`{display}` is an array; expected an index, got `{seg}`"
                ));
            }
            let len = a.len();
            let idx = seg
                .parse::<usize>()
                .ok()
                .filter(|&i| i < len)
                .ok_or_else(|| {
                    format!("index {seg} out of range: `{display}` has {len} entries")
                })?;
            push_segment(display, seg);
            if rest.is_empty() {
                a[idx] = value;
                Ok(())
            } else {
                set_in_value(&mut a[idx], rest, value, display)
            }
        }
        other => Err(format!(
            "`{display}` is a {}, not a table or an array, so it has no `{}`",
            other.type_str(),
            segments[0]
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_nested_and_indexed() {
        let mut t: Table = "a = 1\n[[p]]\nc = 2\n".parse().unwrap();
        assert_eq!(apply(&mut t, "p.0.c=5").unwrap(), "p[0].c");
        assert_eq!(t["p"][0]["c"].as_integer(), Some(5));
        apply(&mut t, "x.y.z = [1, 2]").unwrap();
        assert_eq!(t["x"]["y"]["z"].as_array().unwrap().len(), 2);
        apply(&mut t, "s=second-order").unwrap();
        assert_eq!(t["s"].as_str(), Some("second-order"));
        apply(&mut t, "b={ e = 1.5 }").unwrap();
        assert_eq!(t["b"]["e"].as_float(), Some(1.5));
        assert!(
            apply(&mut t, "p.3.c=1")
                .unwrap_err()
                .contains("out of range")
        );
        assert!(
            apply(&mut t, "q.0.c=1")
                .unwrap_err()
                .contains("does not exist")
        );
        assert!(apply(&mut t, "a.b=1").unwrap_err().contains("integer"));
        assert!(apply(&mut t, "novalue").is_err());
    }
}
