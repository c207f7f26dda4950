//! The text header: its lines (capped at [`MAX_HEADER_BYTES`]), the magic, and the fields we use.

use std::io::{BufRead, Read};
use std::path::Path;

use crate::error::{Error, ErrorKind, Result};
use crate::sample::StoredType;

/// Longest header accepted, in bytes, up to and including the blank line that ends it.
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// The stored type a NRRD `type` field names (any of teem's spellings, case and spacing ignored).
fn parse_type(s: &str) -> Option<StoredType> {
    let s = s.split_whitespace().collect::<Vec<_>>().join(" ").to_ascii_lowercase();
    Some(match s.as_str() {
        "signed char" | "int8" | "int8_t" => StoredType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => StoredType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => StoredType::I16,
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => StoredType::U16,
        "int" | "signed int" | "int32" | "int32_t" => StoredType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => StoredType::U32,
        "longlong"
        | "long long"
        | "long long int"
        | "signed long long"
        | "signed long long int"
        | "int64"
        | "int64_t" => StoredType::I64,
        "ulonglong" | "unsigned long long" | "unsigned long long int" | "uint64" | "uint64_t" => StoredType::U64,
        "float" => StoredType::F32,
        "double" => StoredType::F64,
        _ => return None,
    })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Encoding {
    Raw,
    Gzip,
    Ascii,
    Hex,
}

/// The patient space a NRRD header names; `Unnamed` is `space dimension: 3` without a `space`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum SpaceKind {
    Lps,
    Ras,
    Las,
    Unnamed,
}

impl SpaceKind {
    /// Signs that take a vector in this space to LPS.
    pub(super) const fn lps_signs(self) -> [f64; 3] {
        match self {
            Self::Lps | Self::Unnamed => [1.0, 1.0, 1.0],
            Self::Ras => [-1.0, -1.0, 1.0],
            Self::Las => [1.0, -1.0, 1.0],
        }
    }
}

#[derive(Debug)]
pub(super) struct Header {
    pub(super) stored: StoredType,
    pub(super) sizes: Vec<usize>,
    pub(super) big_endian: bool,
    pub(super) encoding: Encoding,
    pub(super) space: Option<SpaceKind>,
    /// One entry per axis: `None` for `none`.
    pub(super) directions: Option<Vec<Option<[f64; 3]>>>,
    pub(super) origin: Option<[f64; 3]>,
    pub(super) spacings: Option<Vec<f64>>,
    pub(super) kinds: Option<Vec<String>>,
    pub(super) byte_skip: i64,
    pub(super) line_skip: u64,
    pub(super) data_file: Option<String>,
    pub(super) content: Option<String>,
    pub(super) sample_units: Option<String>,
    pub(super) warnings: Vec<String>,
}

/// Reads header lines up to the blank line (or the end of the input); returns them and the bytes used.
pub(super) fn read_header_lines(name: &Path, r: &mut impl BufRead) -> Result<(Vec<String>, u64)> {
    let mut used = 0u64;
    let mut lines = Vec::new();
    let mut buf = Vec::new();
    loop {
        buf.clear();
        let left = MAX_HEADER_BYTES.saturating_sub(used);
        let n = r.by_ref().take(left + 1).read_until(b'\n', &mut buf).map_err(|e| Error::io(name, e))? as u64;
        used += n;
        if used > MAX_HEADER_BYTES {
            return Err(Error::invalid(
                name,
                format!("the header has no blank line within its first {MAX_HEADER_BYTES} bytes"),
            ));
        }
        if n == 0 {
            break; // end of input: a detached header, or a truncated file (caught when reading data)
        }
        let text = String::from_utf8_lossy(&buf);
        let line = text.trim_end_matches(['\n', '\r']);
        if lines.is_empty() {
            check_magic(name, line)?;
        } else if line.is_empty() {
            break;
        }
        lines.push(line.to_string());
        if !buf.ends_with(b"\n") {
            break;
        }
    }
    if lines.is_empty() {
        return Err(Error::new(name, ErrorKind::BadMagic { format: "NRRD", detail: "the file is empty".into() }));
    }
    Ok((lines, used))
}

fn check_magic(name: &Path, line: &str) -> Result<()> {
    let ok = line.len() == 8 && line.starts_with("NRRD000") && matches!(line.as_bytes()[7], b'1'..=b'5');
    if ok {
        return Ok(());
    }
    let shown: String = line.chars().take(16).collect();
    let detail = if line.starts_with("NRRD") {
        format!("unsupported NRRD magic {shown:?} (NRRD0001 to NRRD0005 are read)")
    } else {
        format!("the first line is {shown:?}, not NRRD000x")
    };
    Err(Error::new(name, ErrorKind::BadMagic { format: "NRRD", detail }))
}

pub(super) fn parse_header(name: &Path, lines: &[String]) -> Result<Header> {
    let mut fields: Vec<(String, String)> = Vec::new();
    for (lineno, line) in lines.iter().enumerate().skip(1) {
        if line.starts_with('#') || line.trim().is_empty() {
            continue;
        }
        let field = line.find(": ");
        let kv = line.find(":=");
        match (field, kv) {
            // `key:=value` pairs are free-form and ignored.
            (Some(f), Some(k)) if k < f => {}
            (None, Some(_)) => {}
            (Some(f), _) => {
                let key = line[..f].trim().to_ascii_lowercase();
                let value = line[f + 2..].trim().to_string();
                if matches!(key.as_str(), "data file" | "datafile") && value.split_whitespace().next() == Some("LIST") {
                    // The file names follow as header lines; we read single data files only.
                    return Err(Error::unsupported(
                        name,
                        "\"data file: LIST\" (several data files); only one data file is read",
                    ));
                }
                if fields.iter().any(|(k, _)| *k == key) {
                    return Err(Error::invalid(
                        name,
                        format!("header line {}: field \"{key}\" given twice", lineno + 1),
                    ));
                }
                fields.push((key, value));
            }
            (None, None) => {
                // A field with an empty value ("content:") is harmless; anything else is not NRRD.
                if !line.trim_end().ends_with(':') {
                    let shown: String = line.chars().take(60).collect();
                    return Err(Error::invalid(
                        name,
                        format!("header line {}: {shown:?} is not a \"field: value\" line", lineno + 1),
                    ));
                }
            }
        }
    }
    let get = |k: &str| fields.iter().find(|(key, _)| key == k).map(|(_, v)| v.as_str());
    let mut warnings = Vec::new();

    let type_s = get("type").ok_or_else(|| Error::invalid(name, "the header has no \"type\" field"))?;
    let stored = match parse_type(type_s) {
        Some(t) => t,
        None if type_s.eq_ignore_ascii_case("block") => {
            return Err(Error::unsupported(name, "NRRD type \"block\" is not a sample type we can show"));
        }
        None => return Err(Error::invalid(name, format!("unknown NRRD type {type_s:?}"))),
    };

    let dim_s = get("dimension").ok_or_else(|| Error::invalid(name, "the header has no \"dimension\" field"))?;
    let dimension: usize =
        dim_s.parse().map_err(|_| Error::invalid(name, format!("dimension {dim_s:?} is not a whole number")))?;
    if !(3..=4).contains(&dimension) {
        return Err(Error::unsupported(
            name,
            format!("dimension {dimension}: only 3-D volumes (or 4-D with one axis of size 1) are read"),
        ));
    }

    let sizes_s = get("sizes").ok_or_else(|| Error::invalid(name, "the header has no \"sizes\" field"))?;
    let sizes = sizes_s
        .split_whitespace()
        .map(|s| s.parse::<usize>().ok().filter(|&n| n > 0))
        .collect::<Option<Vec<_>>>()
        .ok_or_else(|| Error::invalid(name, format!("sizes {sizes_s:?} are not positive whole numbers")))?;
    if sizes.len() != dimension {
        return Err(Error::invalid(name, format!("{} sizes for dimension {dimension}", sizes.len())));
    }

    let encoding = match get("encoding").map(str::to_ascii_lowercase).as_deref() {
        Some("raw") => Encoding::Raw,
        Some("gzip" | "gz") => Encoding::Gzip,
        Some("ascii" | "text" | "txt") => Encoding::Ascii,
        Some("hex") => Encoding::Hex,
        Some("bzip2" | "bz2") => {
            return Err(Error::unsupported(name, "bzip2-compressed NRRD; recompress it with gzip (unu save -e gzip)"));
        }
        Some(other) => return Err(Error::unsupported(name, format!("NRRD encoding {other:?}"))),
        None => return Err(Error::invalid(name, "the header has no \"encoding\" field")),
    };

    let big_endian = match get("endian").map(str::to_ascii_lowercase).as_deref() {
        Some("little") => false,
        Some("big") => true,
        Some(other) => return Err(Error::invalid(name, format!("endian {other:?} is neither little nor big"))),
        None => {
            if stored.bytes() > 1 && matches!(encoding, Encoding::Raw | Encoding::Gzip | Encoding::Hex) {
                warnings.push("the header has no \"endian\" field; little-endian assumed".to_string());
            }
            false
        }
    };

    let space = match get("space") {
        Some(s) => Some(parse_space(name, s)?),
        None => match get("space dimension") {
            Some("3") => {
                warnings.push("\"space dimension: 3\" without a named space: directions taken as LPS".to_string());
                Some(SpaceKind::Unnamed)
            }
            Some(d) => {
                return Err(Error::unsupported(name, format!("space dimension {d:?}: only 3-D spaces are read")));
            }
            None => None,
        },
    };
    if let (Some(_), Some(d)) = (get("space"), get("space dimension"))
        && d != "3"
    {
        return Err(Error::invalid(name, format!("space dimension {d:?} contradicts the 3-D space")));
    }

    let directions = match get("space directions") {
        Some(s) => {
            if space.is_none() {
                return Err(Error::invalid(name, "\"space directions\" without \"space\""));
            }
            let toks = vector_tokens(s);
            if toks.len() != dimension {
                return Err(Error::invalid(
                    name,
                    format!("{} space directions for dimension {dimension}: {s:?}", toks.len()),
                ));
            }
            let mut dirs = Vec::with_capacity(dimension);
            for (axis, t) in toks.iter().enumerate() {
                if t.eq_ignore_ascii_case("none") {
                    dirs.push(None);
                } else {
                    dirs.push(Some(parse_vector(name, t, &format!("space direction of axis {axis}"))?));
                }
            }
            Some(dirs)
        }
        None => None,
    };
    let origin = match get("space origin") {
        Some(s) => {
            if space.is_none() {
                return Err(Error::invalid(name, "\"space origin\" without \"space\""));
            }
            Some(parse_vector(name, s.trim(), "space origin")?)
        }
        None => None,
    };
    if space.is_some() && directions.is_none() {
        return Err(Error::invalid(name, "the header names a space but gives no \"space directions\""));
    }

    let spacings = match get("spacings") {
        Some(s) => {
            let v = s
                .split_whitespace()
                .map(|t| t.parse::<f64>().ok().filter(|x| x.is_nan() || (x.is_finite() && *x != 0.0)))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| {
                    Error::invalid(name, format!("spacings {s:?} are not finite non-zero numbers or nan"))
                })?;
            if v.len() != dimension {
                return Err(Error::invalid(name, format!("{} spacings for dimension {dimension}", v.len())));
            }
            Some(v)
        }
        None => None,
    };
    let kinds = get("kinds").map(|s| s.split_whitespace().map(str::to_ascii_lowercase).collect::<Vec<_>>());

    let byte_skip = match get("byte skip").or_else(|| get("byteskip")) {
        Some(s) => {
            let b: i64 = s.parse().map_err(|_| Error::invalid(name, format!("byte skip {s:?} is not a number")))?;
            if b < -1 {
                return Err(Error::invalid(name, format!("byte skip {b} is below -1")));
            }
            if b == -1 && encoding != Encoding::Raw {
                return Err(Error::invalid(name, "\"byte skip: -1\" is only allowed with raw encoding"));
            }
            b
        }
        None => 0,
    };
    let line_skip = match get("line skip").or_else(|| get("lineskip")) {
        Some(s) => s.parse::<u64>().map_err(|_| Error::invalid(name, format!("line skip {s:?} is not a number")))?,
        None => 0,
    };
    let data_file = get("data file").or_else(|| get("datafile")).map(str::to_string);
    if let Some(df) = &data_file {
        let first = df.split_whitespace().next().unwrap_or("");
        if first == "LIST" || (df.contains('%') && df.split_whitespace().count() >= 4) {
            return Err(Error::unsupported(
                name,
                format!("multi-file \"data file: {df}\" (LIST or format-string forms); only one data file is read"),
            ));
        }
    }
    if let Some(u) = get("space units") {
        let units: Vec<&str> = u.split_whitespace().map(|t| t.trim_matches('"')).collect();
        if units.iter().any(|t| !t.is_empty() && *t != "mm") {
            warnings.push(format!("space units {u} are not mm; coordinates are used as mm"));
        }
    }

    Ok(Header {
        stored,
        sizes,
        big_endian,
        encoding,
        space,
        directions,
        origin,
        spacings,
        kinds,
        byte_skip,
        line_skip,
        data_file,
        content: get("content").map(str::to_string),
        sample_units: get("sample units").map(|s| s.trim_matches('"').to_string()),
        warnings,
    })
}

fn parse_space(name: &Path, s: &str) -> Result<SpaceKind> {
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "left-posterior-superior" | "lps" => SpaceKind::Lps,
        "right-anterior-superior" | "ras" => SpaceKind::Ras,
        "left-anterior-superior" | "las" => SpaceKind::Las,
        "right-anterior-superior-time"
        | "left-anterior-superior-time"
        | "left-posterior-superior-time"
        | "rast"
        | "last"
        | "lpst"
        | "scanner-xyz-time"
        | "3d-right-handed-time"
        | "3d-left-handed-time" => {
            return Err(Error::unsupported(name, format!("space {s:?} has a time axis; only 3-D spaces are read")));
        }
        "scanner-xyz" | "3d-right-handed" | "3d-left-handed" => {
            return Err(Error::unsupported(
                name,
                format!("space {s:?} has no patient orientation; LPS, RAS or LAS is needed"),
            ));
        }
        _ => return Err(Error::invalid(name, format!("unknown NRRD space {s:?}"))),
    })
}

/// Splits `(a,b,c) none (d, e, f)` into `["(a,b,c)", "none", "(d, e, f)"]`.
fn vector_tokens(s: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut depth = 0u32;
    for c in s.chars() {
        match c {
            '(' => {
                depth += 1;
                cur.push(c);
            }
            ')' => {
                depth = depth.saturating_sub(1);
                cur.push(c);
            }
            c if c.is_whitespace() && depth == 0 => {
                if !cur.is_empty() {
                    out.push(std::mem::take(&mut cur));
                }
            }
            c => cur.push(c),
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

fn parse_vector(name: &Path, t: &str, what: &str) -> Result<[f64; 3]> {
    let bad = || Error::invalid(name, format!("{what} {t:?} is not a vector (x,y,z) of finite numbers"));
    let inner = t.strip_prefix('(').and_then(|s| s.strip_suffix(')')).ok_or_else(bad)?;
    let v =
        inner.split(',').map(|x| x.trim().parse::<f64>().ok().filter(|x| x.is_finite())).collect::<Option<Vec<_>>>();
    match v.as_deref() {
        Some(&[x, y, z]) => Ok([x, y, z]),
        _ => Err(bad()),
    }
}
