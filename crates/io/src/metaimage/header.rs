//! The text header: its `Key = Value` lines up to `ElementDataFile` (capped at [`MAX_HEADER_BYTES`]), and the
//! fields we use, checked.

use std::io::{BufRead, Read};
use std::path::Path;

use crate::error::{Error, ErrorKind, Result};
use crate::sample::StoredType;

/// Longest header accepted, in bytes, up to and including the `ElementDataFile` line that ends it.
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Where the samples are.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) enum DataFile {
    /// `ElementDataFile = LOCAL`: right after the header, in the same file (`.mha`).
    Local,
    /// A file beside the header (`.mhd` + `.raw`), relative to the header's folder unless absolute.
    Detached(String),
}

/// The header's fields, checked (module docs of [`super`]).
#[derive(Debug)]
pub(super) struct Header {
    pub(super) ndims: usize,
    pub(super) dim_size: Vec<usize>,
    pub(super) stored: StoredType,
    /// `ElementNumberOfChannels`: samples a voxel, interleaved (1 for a scalar volume, 3 for a displacement field).
    pub(super) channels: usize,
    pub(super) big_endian: bool,
    pub(super) compressed: bool,
    pub(super) compressed_size: Option<u64>,
    /// `HeaderSize`: bytes skipped before the samples; `None` for `-1` (the samples are the file's last bytes).
    pub(super) byte_skip: Option<u64>,
    /// `ElementSpacing` (else `ElementSize`), `NDims` values.
    pub(super) spacing: Option<Vec<f64>>,
    /// `Offset` / `Position` / `Origin`, `NDims` values.
    pub(super) offset: Option<Vec<f64>>,
    /// `TransformMatrix` / `Rotation` / `Orientation`, `NDims²` values, column by column as ITK writes them.
    pub(super) direction: Option<Vec<f64>>,
    pub(super) data_file: DataFile,
    pub(super) comment: Option<String>,
}

/// One header line: its 1-based number, key and value.
pub(super) type Field = (usize, String, String);

/// Reads the header lines up to and including `ElementDataFile` (the last field of every MetaImage header); returns
/// the fields and the bytes the header takes.
pub(super) fn read_header_lines(name: &Path, r: &mut impl BufRead) -> Result<(Vec<Field>, u64)> {
    let mut used = 0u64;
    let mut fields = Vec::new();
    let mut buf = Vec::new();
    let mut lineno = 0usize;
    loop {
        buf.clear();
        let left = MAX_HEADER_BYTES.saturating_sub(used);
        let n = r.by_ref().take(left + 1).read_until(b'\n', &mut buf).map_err(|e| Error::io(name, e))? as u64;
        used += n;
        lineno += 1;
        if used > MAX_HEADER_BYTES {
            return Err(Error::invalid(
                name,
                format!("the header has no ElementDataFile line within its first {MAX_HEADER_BYTES} bytes"),
            ));
        }
        if n == 0 {
            return Err(if fields.is_empty() {
                Error::new(name, ErrorKind::BadMagic { format: "MetaImage", detail: "the file is empty".into() })
            } else {
                Error::truncated(name, "the header ends without an ElementDataFile line (the last field of a header)")
            });
        }
        let text = String::from_utf8_lossy(&buf);
        let line = text.trim_end_matches(['\n', '\r']);
        if line.trim().is_empty() {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            let shown: String = line.chars().take(60).collect();
            if fields.is_empty() {
                return Err(Error::new(
                    name,
                    ErrorKind::BadMagic {
                        format: "MetaImage",
                        detail: format!("the first line is {shown:?}, not \"ObjectType = Image\""),
                    },
                ));
            }
            return Err(Error::invalid(name, format!("header line {lineno}: {shown:?} is not a \"Key = Value\" line")));
        };
        let (key, value) = (key.trim().to_string(), value.trim().to_string());
        let last = key.eq_ignore_ascii_case("ElementDataFile");
        fields.push((lineno, key, value));
        if last {
            return Ok((fields, used));
        }
    }
}

/// The stored type an `ElementType` names, as MetaIO sizes them (`MET_LONG` is 4 bytes there, whatever C's `long`).
fn parse_type(s: &str) -> Option<StoredType> {
    Some(match s {
        "MET_CHAR" | "MET_ASCII_CHAR" => StoredType::I8,
        "MET_UCHAR" => StoredType::U8,
        "MET_SHORT" => StoredType::I16,
        "MET_USHORT" => StoredType::U16,
        "MET_INT" | "MET_LONG" => StoredType::I32,
        "MET_UINT" | "MET_ULONG" => StoredType::U32,
        "MET_LONG_LONG" => StoredType::I64,
        "MET_ULONG_LONG" => StoredType::U64,
        "MET_FLOAT" => StoredType::F32,
        "MET_DOUBLE" => StoredType::F64,
        _ => return None,
    })
}

/// The header's fields from its lines; `name` is used in errors.
pub(super) fn parse_header(name: &Path, lines: &[Field]) -> Result<Header> {
    // Each field we use, with the other spellings MetaIO accepts for it.
    const SYNONYMS: [&[&str]; 4] = [
        &["TransformMatrix", "Rotation", "Orientation"],
        &["Offset", "Position", "Origin"],
        &["BinaryDataByteOrderMSB", "ElementByteOrderMSB"],
        &["ElementSpacing"],
    ];
    let mut seen: Vec<&str> = Vec::new();
    for (lineno, key, _) in lines {
        if seen.iter().any(|k| k.eq_ignore_ascii_case(key)) {
            return Err(Error::invalid(name, format!("header line {lineno}: field \"{key}\" given twice")));
        }
        seen.push(key);
    }
    let get_one = |k: &str| lines.iter().find(|(_, key, _)| key.eq_ignore_ascii_case(k)).map(|(l, _, v)| (*l, v));
    // A field and its synonyms: at most one of them, or all with the same value.
    let get = |k: &str| -> Result<Option<(usize, &String)>> {
        let names = SYNONYMS.iter().find(|s| s[0] == k).copied().unwrap_or(&[]);
        let mut found = get_one(k);
        for other in names.iter().skip(1) {
            if let Some((l, v)) = get_one(other) {
                match found {
                    Some((_, f)) if f != v => {
                        return Err(Error::invalid(
                            name,
                            format!("header line {l}: {other} = {v} contradicts {k} = {f}, which means the same"),
                        ));
                    }
                    _ => found = Some((l, v)),
                }
            }
        }
        Ok(found)
    };

    let object_type = get_one("ObjectType").map(|(_, v)| v.as_str());
    if let Some(t) = object_type
        && !t.eq_ignore_ascii_case("Image")
    {
        return Err(Error::unsupported(
            name,
            format!("ObjectType = {t}: only MetaImage images (ObjectType = Image) are read"),
        ));
    }

    let (ndims_line, ndims_s) =
        get_one("NDims").ok_or_else(|| Error::invalid(name, "the header has no NDims field"))?;
    let ndims: usize = ndims_s.parse().map_err(|_| {
        Error::invalid(name, format!("header line {ndims_line}: NDims {ndims_s:?} is not a whole number"))
    })?;
    if !(3..=4).contains(&ndims) {
        return Err(Error::unsupported(
            name,
            format!("NDims = {ndims}: only 3-D volumes (and 4-D files, one frame at a time) are read"),
        ));
    }

    let (dim_line, dim_s) =
        get_one("DimSize").ok_or_else(|| Error::invalid(name, "the header has no DimSize field"))?;
    let dim_size = dim_s
        .split_whitespace()
        .map(|s| s.parse::<usize>().ok().filter(|&n| n > 0))
        .collect::<Option<Vec<_>>>()
        .filter(|v| v.len() == ndims)
        .ok_or_else(|| {
            Error::invalid(
                name,
                format!(
                    "header line {dim_line}: DimSize {dim_s:?} is not {ndims} positive whole numbers (NDims = {ndims})"
                ),
            )
        })?;

    let channels = match get_one("ElementNumberOfChannels") {
        Some((l, v)) => v.parse::<usize>().ok().filter(|&c| c > 0).ok_or_else(|| {
            Error::invalid(
                name,
                format!("header line {l}: ElementNumberOfChannels {v:?} is not a positive whole number"),
            )
        })?,
        None => 1,
    };

    let (type_line, type_s) =
        get_one("ElementType").ok_or_else(|| Error::invalid(name, "the header has no ElementType field"))?;
    let stored = match parse_type(type_s) {
        Some(t) => t,
        None if type_s.ends_with("_ARRAY") || type_s.ends_with("_MATRIX") => {
            return Err(Error::unsupported(
                name,
                format!("ElementType = {type_s}: a vector or matrix type; only scalar volumes are read"),
            ));
        }
        None => {
            return Err(Error::invalid(
                name,
                format!(
                    "header line {type_line}: ElementType {type_s:?} is not a MetaImage scalar type (MET_UCHAR, \
                     MET_CHAR, MET_SHORT, MET_USHORT, MET_INT, MET_UINT, MET_LONG, MET_ULONG, MET_LONG_LONG, \
                     MET_ULONG_LONG, MET_FLOAT, MET_DOUBLE)"
                ),
            ));
        }
    };

    let boolean = |field: &str| -> Result<Option<bool>> {
        let Some((l, v)) = get(field)? else { return Ok(None) };
        match v.to_ascii_lowercase().as_str() {
            "true" | "t" | "1" => Ok(Some(true)),
            "false" | "f" | "0" => Ok(Some(false)),
            _ => Err(Error::invalid(name, format!("header line {l}: {field} {v:?} is neither True nor False"))),
        }
    };
    // MetaIO's default is text samples, which ITK never writes.
    if !boolean("BinaryData")?.unwrap_or(false) {
        return Err(Error::unsupported(
            name,
            "samples stored as text (BinaryData = False, or no BinaryData field); only binary MetaImage data are read",
        ));
    }
    let big_endian = boolean("BinaryDataByteOrderMSB")?.unwrap_or(false);
    let compressed = boolean("CompressedData")?.unwrap_or(false);
    let compressed_size = match get_one("CompressedDataSize") {
        Some((l, v)) => Some(v.parse::<u64>().map_err(|_| {
            Error::invalid(name, format!("header line {l}: CompressedDataSize {v:?} is not a whole number of bytes"))
        })?),
        None => None,
    };
    if compressed_size.is_some() && !compressed {
        return Err(Error::invalid(name, "CompressedDataSize is given but CompressedData is not True"));
    }

    let byte_skip = match get_one("HeaderSize") {
        Some((_, v)) if v == "-1" => None,
        Some((l, v)) => Some(v.parse::<u64>().map_err(|_| {
            Error::invalid(name, format!("header line {l}: HeaderSize {v:?} is neither -1 nor a whole number of bytes"))
        })?),
        None => Some(0),
    };
    if byte_skip.is_none() && compressed {
        return Err(Error::invalid(name, "HeaderSize = -1 (the data are the file's last bytes) with compressed data"));
    }

    let numbers = |field: &str, count: usize| -> Result<Option<Vec<f64>>> {
        let Some((l, v)) = get(field)? else { return Ok(None) };
        let values =
            v.split_whitespace().map(|t| t.parse::<f64>().ok().filter(|x| x.is_finite())).collect::<Option<Vec<_>>>();
        match values {
            Some(values) if values.len() == count => Ok(Some(values)),
            _ => Err(Error::invalid(
                name,
                format!("header line {l}: {field} {v:?} is not {count} finite numbers (NDims = {ndims})"),
            )),
        }
    };
    let spacing = match numbers("ElementSpacing", ndims)? {
        Some(s) => Some(s),
        None => numbers("ElementSize", ndims)?,
    };
    let offset = numbers("Offset", ndims)?;
    let direction = numbers("TransformMatrix", ndims * ndims)?;

    let (_, file_s) = get_one("ElementDataFile").ok_or_else(|| Error::invalid(name, "no ElementDataFile field"))?;
    let data_file = if file_s.eq_ignore_ascii_case("LOCAL") {
        DataFile::Local
    } else if file_s.split_whitespace().next() == Some("LIST") {
        return Err(Error::unsupported(
            name,
            "ElementDataFile = LIST (one data file per slice or frame); only one data file is read",
        ));
    } else if file_s.contains('%') && file_s.split_whitespace().count() >= 4 {
        return Err(Error::unsupported(
            name,
            format!("ElementDataFile = {file_s} (numbered data files); only one data file is read"),
        ));
    } else if file_s.is_empty() {
        return Err(Error::invalid(name, "ElementDataFile is empty"));
    } else {
        DataFile::Detached(file_s.clone())
    };

    Ok(Header {
        ndims,
        dim_size,
        stored,
        channels,
        big_endian,
        compressed,
        compressed_size,
        byte_skip,
        spacing,
        offset,
        direction,
        data_file,
        comment: get_one("Comment").map(|(_, v)| v.clone()).filter(|v| !v.is_empty()),
    })
}

/// Whether `head` (a file's first bytes) starts as a MetaImage header does: `ObjectType = …` first, as MetaIO and ITK
/// write it.
#[must_use]
pub fn looks_like_metaimage(head: &[u8]) -> bool {
    let start = head.iter().position(|b| !b.is_ascii_whitespace()).unwrap_or(head.len());
    let Some(rest) = head[start..].strip_prefix(b"ObjectType") else { return false };
    rest.iter().find(|b| **b != b' ' && **b != b'\t') == Some(&b'=')
}
