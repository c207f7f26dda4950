//! The parameter file's syntax: `(Name value …)` lines, quoted strings, bare numbers, `//` comments (see
//! [`super`]); a leaf that the reader and the dispatcher share.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// The longest parameter file read, bytes: a B-spline of a million control points in 3-D is about 60 MB of text.
pub(super) const MAX_FILE_BYTES: u64 = 256 << 20;

/// One value of a parameter: a quoted string or a bare token (a number, or an unquoted word).
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Value {
    Text(String),
    Bare(String),
}

/// A parameter file: its parameters in order, each with its 1-based line.
#[derive(Clone, Debug, Default)]
pub(super) struct ParameterMap {
    entries: Vec<(usize, String, Vec<Value>)>,
}

impl ParameterMap {
    pub(super) fn get(&self, key: &str) -> Option<(usize, &[Value])> {
        self.entries.iter().find(|(_, k, _)| k == key).map(|(l, _, v)| (*l, v.as_slice()))
    }

    /// The one string value of `key`, if given.
    pub(super) fn text(&self, name: &Path, key: &str) -> Result<Option<&str>> {
        match self.get(key) {
            None => Ok(None),
            Some((_, [Value::Text(s) | Value::Bare(s)])) => Ok(Some(s)),
            Some((line, values)) => {
                Err(Error::invalid(name, format!("line {line}: ({key} …) has {} values, one expected", values.len())))
            }
        }
    }

    /// The numbers of `key`, if given.
    pub(super) fn numbers(&self, name: &Path, key: &str) -> Result<Option<Vec<f64>>> {
        let Some((line, values)) = self.get(key) else { return Ok(None) };
        values
            .iter()
            .map(|v| match v {
                Value::Bare(s) => s.parse::<f64>().ok().filter(|x| x.is_finite()),
                Value::Text(_) => None,
            })
            .collect::<Option<Vec<_>>>()
            .map(Some)
            .ok_or_else(|| {
                Error::invalid(name, format!("line {line}: ({key} …) holds a value that is not a finite number"))
            })
    }

    /// Exactly `count` numbers of `key`.
    pub(super) fn numbers_n(&self, name: &Path, key: &str, count: usize) -> Result<Vec<f64>> {
        let v = self
            .numbers(name, key)?
            .ok_or_else(|| Error::invalid(name, format!("the file has no ({key} …) parameter")))?;
        if v.len() != count {
            let line = self.get(key).map_or(0, |(l, _)| l);
            return Err(Error::invalid(
                name,
                format!("line {line}: ({key} …) has {} numbers, {count} expected", v.len()),
            ));
        }
        Ok(v)
    }
}

/// Whether `text` (a file's start) reads as an elastix parameter file: its first line that is neither blank nor a
/// `//` comment opens with `(`.
#[must_use]
pub fn looks_like_parameter_file(text: &[u8]) -> bool {
    let text = String::from_utf8_lossy(text);
    text.lines().map(str::trim).find(|l| !l.is_empty() && !l.starts_with("//")).is_some_and(|l| l.starts_with('('))
}

/// Parses a parameter file's text; `name` is used in errors, which give the line.
pub(super) fn parse(name: &Path, text: &str) -> Result<ParameterMap> {
    let mut map = ParameterMap::default();
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = strip_comment(raw).trim();
        if line.is_empty() {
            continue;
        }
        let shown: String = line.chars().take(60).collect();
        let inner = line
            .strip_prefix('(')
            .and_then(|l| l.strip_suffix(')'))
            .ok_or_else(|| Error::invalid(name, format!("line {line_no}: {shown:?} is not a (Name value …) line")))?;
        let values = tokens(inner)
            .ok_or_else(|| Error::invalid(name, format!("line {line_no}: {shown:?} has an unclosed quote")))?;
        let mut values = values.into_iter();
        let Some(Value::Bare(key)) = values.next() else {
            return Err(Error::invalid(name, format!("line {line_no}: {shown:?} does not start with a name")));
        };
        if let Some((first, _)) = map.get(&key) {
            return Err(Error::invalid(
                name,
                format!("line {line_no}: ({key} …) is given again (first on line {first})"),
            ));
        }
        map.entries.push((line_no, key, values.collect()));
    }
    Ok(map)
}

/// `line` up to a `//` that is not inside quotes.
fn strip_comment(line: &str) -> &str {
    let mut quoted = false;
    let bytes = line.as_bytes();
    for (i, &b) in bytes.iter().enumerate() {
        match b {
            b'"' => quoted = !quoted,
            b'/' if !quoted && bytes.get(i + 1) == Some(&b'/') => return &line[..i],
            _ => {}
        }
    }
    line
}

/// The whitespace-separated values of a line's inside; `None` for an unclosed quote.
fn tokens(inner: &str) -> Option<Vec<Value>> {
    let mut out = Vec::new();
    let mut rest = inner.trim_start();
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix('"') {
            let end = after.find('"')?;
            out.push(Value::Text(after[..end].to_owned()));
            rest = after[end + 1..].trim_start();
        } else {
            let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
            out.push(Value::Bare(rest[..end].to_owned()));
            rest = rest[end..].trim_start();
        }
    }
    Some(out)
}

/// Reads and parses the parameter file at `path` (a regular file of at most [`MAX_FILE_BYTES`], UTF-8).
pub(super) fn read_file(path: &Path) -> Result<ParameterMap> {
    let len = crate::files::check_regular_file(path)?.len();
    if len > MAX_FILE_BYTES {
        return Err(Error::invalid(path, format!("{len} bytes is too long for a transform parameter file")));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_bytes(path, &bytes)
}

/// Parses a parameter file's bytes (at most [`MAX_FILE_BYTES`], UTF-8); `name` is used in errors.
pub(super) fn parse_bytes(name: &Path, bytes: &[u8]) -> Result<ParameterMap> {
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(Error::invalid(name, format!("{} bytes is too long for a transform parameter file", bytes.len())));
    }
    let text = std::str::from_utf8(bytes).map_err(|_| Error::invalid(name, "the parameter file is not UTF-8 text"))?;
    parse(name, text)
}

/// A file that the parameter file `name` names under `key`: beside `name`, else as given.
pub(super) fn find_beside(name: &Path, file: &str, key: &str) -> Result<PathBuf> {
    let given = PathBuf::from(file);
    let beside = name.parent().map(|d| d.join(&given));
    beside
        .filter(|p| p.is_file())
        .or_else(|| given.is_file().then_some(given.clone()))
        .ok_or_else(|| Error::invalid(name, format!("its {key} {file:?} is neither beside it nor where it says")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_comments_quotes_and_bad_lines() {
        let name = Path::new("p.txt");
        let text = "// elastix\n\n(Transform \"EulerTransform\") // rigid\n(TransformParameters 1 -2.5 3e-1)\n(Note \"a // b\")\n";
        let map = parse(name, text).expect("parse");
        assert_eq!(map.text(name, "Transform").expect("one"), Some("EulerTransform"));
        assert_eq!(map.numbers(name, "TransformParameters").expect("numbers"), Some(vec![1.0, -2.5, 0.3]));
        assert_eq!(map.text(name, "Note").expect("one"), Some("a // b"));
        assert!(map.text(name, "TransformParameters").is_err(), "three values are not one");
        assert!(map.numbers(name, "Transform").is_err(), "a string is not a number");
        for (bad, needle) in [
            ("(Transform \"Euler)\n", "unclosed quote"),
            ("Transform \"Euler\"\n", "not a (Name value …) line"),
            ("(A 1)\n(A 2)\n", "line 2: (A …) is given again (first on line 1)"),
            ("(\"A\" 1)\n", "does not start with a name"),
            ("(A nan)\n", ""),
        ] {
            let map = parse(name, bad);
            if needle.is_empty() {
                assert!(map.expect("parses").numbers(name, "A").is_err(), "NaN is not a finite number");
            } else {
                let e = map.expect_err(bad).to_string();
                assert!(e.starts_with("p.txt: ") && e.contains(needle), "{e}");
            }
        }
        assert!(looks_like_parameter_file(b"// c\n\n  (Transform \"X\")"));
        assert!(!looks_like_parameter_file(b"#Insight Transform File V1.0\n"));
    }
}
