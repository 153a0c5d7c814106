//! Maps a field path (`particles[0].diameter.uniform.min`) back to a line and
//! column of the scenario text.

use toml::de::{DeTable, DeValue};

use super::Location;

/// 1-based line and column (in characters) of byte `offset` in `text`.
pub(super) fn offset_to_location(text: &str, offset: usize) -> Location {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before[line_start..].chars().count() + 1;
    Location { line, column }
}

enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

fn parse_path(path: &str) -> Option<Vec<Seg<'_>>> {
    let mut out = Vec::new();
    for part in path.split('.') {
        let (key, mut rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if !key.is_empty() {
            out.push(Seg::Key(key));
        }
        while let Some(r) = rest.strip_prefix('[') {
            let close = r.find(']')?;
            out.push(Seg::Index(r[..close].parse().ok()?));
            rest = &r[close + 1..];
        }
    }
    Some(out)
}

fn keep(best: &mut Option<std::ops::Range<usize>>, span: std::ops::Range<usize>) {
    if !span.is_empty() {
        *best = Some(span);
    }
}

/// Location of the deepest element of `path` found in `text`: the value for
/// scalars and arrays, the key (or header) for tables; with `at_key`, always
/// the key.
pub(super) fn locate(text: &str, path: &str, at_key: bool) -> Option<Location> {
    let segs = parse_path(path)?;
    let root = DeTable::parse(text).ok()?;
    let mut table: Option<&DeTable> = Some(root.get_ref());
    let mut value: Option<&DeValue> = None;
    let mut best: Option<std::ops::Range<usize>> = None;
    for seg in segs {
        let next = match (seg, table, value) {
            (Seg::Key(k), Some(t), _) => {
                t.iter()
                    .find(|(key, _)| key.get_ref() == k)
                    .map(|(key, v)| {
                        keep(&mut best, key.span());
                        v
                    })
            }
            (Seg::Index(i), _, Some(DeValue::Array(a))) => {
                a.get(i).inspect(|v| keep(&mut best, v.span()))
            }
            _ => None,
        };
        let Some(v) = next else { break };
        match v.get_ref() {
            DeValue::Table(t) => {
                table = Some(t);
                value = None;
            }
            DeValue::Array(_) => {
                table = None;
                value = Some(v.get_ref());
                if !at_key {
                    keep(&mut best, v.span());
                }
            }
            other => {
                table = None;
                value = Some(other);
                if !at_key {
                    keep(&mut best, v.span());
                }
            }
        }
    }
    best.map(|s| offset_to_location(text, s.start))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_nested_values() {
        let text = "seed = 1\n[[particles]]\nname = \"a\"\n[[particles]]\nname = \"b\"\ndiameter = { uniform = { min = 1, max = 2 } }\n";
        assert_eq!(
            locate(text, "seed", false),
            Some(Location { line: 1, column: 8 })
        );
        assert_eq!(
            locate(text, "particles[1].name", false),
            Some(Location { line: 5, column: 8 })
        );
        let l = locate(text, "particles[1].diameter.uniform.max", false).unwrap();
        assert_eq!(l.line, 6);
        assert_eq!(&text.lines().nth(5).unwrap()[l.column - 1..l.column], "2");
        assert_eq!(
            locate(text, "particles[1].name", true),
            Some(Location { line: 5, column: 1 })
        );
    }
}
