//! NRRD (`.nrrd`, `.nhdr`): reader and writer.
//!
//! # The format
//!
//! A NRRD file is a text header followed by the samples (Kindlmann, *Definition of NRRD File
//! Format*, teem.sourceforge.net/nrrd/format.html):
//!
//! ```text
//! NRRD0004                         magic, NRRD0001 … NRRD0005
//! # a comment
//! type: short                      sample type (C names and their aliases)
//! dimension: 3
//! space: left-posterior-superior   or right-anterior-superior, left-anterior-superior
//! sizes: 512 512 48                fastest axis first
//! space directions: (0.57,0,0) (0,0.57,0) (0,0,5)   one column of lps_from_index per axis, `none` for non-spatial axes
//! space origin: (-146,-325,-777.5) position of the centre of the first sample
//! endian: little
//! encoding: gzip                   raw, gzip (gz), ascii (text, txt), hex; bzip2 is refused
//! key:=value                       free key/value pairs, ignored
//!                                  a blank line ends the header; the data follow
//! ```
//!
//! A detached header (`.nhdr`) names its data with `data file: name`, relative to the header's
//! folder; `line skip` and `byte skip` skip lines and bytes before the data (`byte skip: -1` means
//! "the data are the last bytes of the file", raw only). For compressed encodings the byte skip
//! counts decompressed bytes, as in teem and pynrrd.
//!
//! # Our conventions
//!
//! - Geometry: `lps_from_index = [d_0 d_1 d_2 | o]` with the space directions `d_a` as columns
//!   and the origin `o`, both converted to LPS from the `space` field (RAS negates x and y, LAS
//!   negates y) → [`GeometrySource::NrrdSpace`]. Without a space, `spacings` give an
//!   axis-aligned diagonal with origin 0 → [`GeometrySource::NrrdSpacings`] (unit spacing, with a
//!   warning, when even those are missing).
//! - Dimension 3, or 4 with one non-spatial axis of size 1 (anywhere), which is dropped; real
//!   vector or time-series data are refused.
//! - Sample types follow `docs/fixture-manifest.md`: u8, i16, u16 and f32 are kept, i8 becomes
//!   i16, every other type becomes f32. NRRD has no rescale.
//! - Bad input never panics: the header is capped at [`MAX_HEADER_BYTES`], numbers are checked,
//!   [`crate::volume::check_allocation`] runs before any voxel buffer exists, raw data are checked
//!   against the file length first, and samples are converted in chunks, so the peak memory is
//!   the output plus one chunk. The output buffer is allocated fallibly
//!   ([`crate::volume::try_with_capacity`]): memory the system refuses is an error naming the file.
//! - No hang: the header and a detached data file must be regular files (a named pipe or a device
//!   such as `/dev/zero` is refused before it is opened), and every skip and scan of the data
//!   (line skip, byte skip, gzip, hex, ASCII) reads at most the bytes the file had when it was
//!   opened; a `line skip` whose line does not end before them is a truncated file.
//! - The writer ([`write()`], [`write_with`]) writes NRRD0004 in LPS with the directions and the
//!   origin printed with Rust's shortest round-trip formatting (exact f64), little-endian,
//!   gzip-compressed unless asked otherwise, through [`crate::write_atomic`].

use std::fs::File;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};

use flate2::Compression;
use flate2::read::MultiGzDecoder;
use flate2::write::GzEncoder;
use nalgebra::Matrix3;

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::options::LoadOptions;
use crate::sample::{self, StoredType};
use crate::volume::{GeometrySource, Metadata, SampleType, Volume, VoxelData, check_allocation};

/// Longest header accepted, in bytes, up to and including the blank line that ends it.
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Samples are decoded this many bytes at a time (a multiple of every sample size).
const CHUNK_BYTES: usize = 1 << 20;

/// Deflate cannot expand data by more than about 1032:1; a gzip payload claiming more is truncated.
const MAX_DEFLATE_RATIO: u64 = 1032;

/// Options for [`write_with`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NrrdWriteOptions {
    /// `encoding: gzip` when true (the default), `encoding: raw` when false.
    pub gzip: bool,
}

impl Default for NrrdWriteOptions {
    fn default() -> Self {
        Self { gzip: true }
    }
}

/// Reads the NRRD file (attached `.nrrd` or detached `.nhdr`) at `path`.
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    crate::check_regular_file(path)?;
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let base = path.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    read_from(path, BufReader::new(file), len, Some(&base), opts)
}

/// Reads a NRRD file held in memory; `name` is used in errors. Detached data files are refused.
pub fn read_bytes(name: &Path, bytes: &[u8], opts: &mut LoadOptions) -> Result<Volume> {
    read_from(name, bytes, bytes.len() as u64, None, opts)
}

/// Writes `volume` as a gzip-compressed NRRD0004 file in LPS.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    write_with(path, volume, NrrdWriteOptions::default())
}

/// Writes `volume` as NRRD0004 in LPS, gzip-compressed or raw as `options` say.
pub fn write_with(path: &Path, volume: &Volume, options: NrrdWriteOptions) -> Result<()> {
    let n = crate::volume::checked_voxel_count(path, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(path, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    if !volume.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    let header = header_text(volume, options);
    crate::write_atomic(path, |w| {
        w.write_all(header.as_bytes())?;
        if options.gzip {
            let mut gz = GzEncoder::new(w, Compression::default());
            write_samples(&mut gz, &volume.data)?;
            gz.finish()?;
            Ok(())
        } else {
            write_samples(w, &volume.data)
        }
    })
}

fn header_text(volume: &Volume, options: NrrdWriteOptions) -> String {
    use std::fmt::Write as _;
    let type_name = match volume.sample_type() {
        // teem's canonical names, which every NRRD reader knows.
        SampleType::U8 => "unsigned char",
        SampleType::I16 => "short",
        SampleType::U16 => "unsigned short",
        SampleType::F32 => "float",
    };
    let lps_from_index = &volume.lps_from_index;
    let l = lps_from_index.linear();
    let o = lps_from_index.translation();
    let col = |c: usize| format!("({:?},{:?},{:?})", l[(0, c)], l[(1, c)], l[(2, c)]);
    let [nx, ny, nz] = volume.dims;
    let mut h = String::from("NRRD0004\n# Complete NRRD file format specification at:\n");
    h.push_str("# http://teem.sourceforge.net/nrrd/format.html\n");
    let _ = writeln!(h, "type: {type_name}");
    h.push_str("dimension: 3\nspace: left-posterior-superior\n");
    let _ = writeln!(h, "sizes: {nx} {ny} {nz}");
    let _ = writeln!(h, "space directions: {} {} {}", col(0), col(1), col(2));
    h.push_str("kinds: domain domain domain\n");
    if volume.sample_type().bytes() > 1 {
        h.push_str("endian: little\n");
    }
    let _ = writeln!(h, "encoding: {}", if options.gzip { "gzip" } else { "raw" });
    let _ = writeln!(h, "space origin: ({:?},{:?},{:?})", o[0], o[1], o[2]);
    if let Some(desc) = &volume.metadata.description {
        let one_line: String = desc.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
        if !one_line.trim().is_empty() {
            let _ = writeln!(h, "content: {}", one_line.trim());
        }
    }
    h.push('\n');
    h
}

/// Writes the samples little-endian, a bounded chunk at a time (no full-size byte copy).
fn write_samples(w: &mut dyn Write, data: &VoxelData) -> io::Result<()> {
    data.try_for_each_le_chunk(|b| w.write_all(b))
}

// ---------------------------------------------------------------------------------------------
// Header

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
enum Encoding {
    Raw,
    Gzip,
    Ascii,
    Hex,
}

/// The patient space a NRRD header names; `Unnamed` is `space dimension: 3` without a `space`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SpaceKind {
    Lps,
    Ras,
    Las,
    Unnamed,
}

impl SpaceKind {
    /// Signs that take a vector in this space to LPS.
    const fn lps_signs(self) -> [f64; 3] {
        match self {
            Self::Lps | Self::Unnamed => [1.0, 1.0, 1.0],
            Self::Ras => [-1.0, -1.0, 1.0],
            Self::Las => [1.0, -1.0, 1.0],
        }
    }
}

#[derive(Debug)]
struct Header {
    stored: StoredType,
    sizes: Vec<usize>,
    big_endian: bool,
    encoding: Encoding,
    space: Option<SpaceKind>,
    /// One entry per axis: `None` for `none`.
    directions: Option<Vec<Option<[f64; 3]>>>,
    origin: Option<[f64; 3]>,
    spacings: Option<Vec<f64>>,
    kinds: Option<Vec<String>>,
    byte_skip: i64,
    line_skip: u64,
    data_file: Option<String>,
    content: Option<String>,
    sample_units: Option<String>,
    warnings: Vec<String>,
}

/// Reads header lines up to the blank line (or the end of the input); returns them and the bytes used.
fn read_header_lines(name: &Path, r: &mut impl BufRead) -> Result<(Vec<String>, u64)> {
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

fn parse_header(name: &Path, lines: &[String]) -> Result<Header> {
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

/// The three spatial axes, `lps_from_index` and where it came from.
struct Geometry {
    dims: [usize; 3],
    lps_from_index: Transform<Lps, Index>,
    source: GeometrySource,
}

fn geometry(name: &Path, h: &mut Header) -> Result<Geometry> {
    let dimension = h.sizes.len();
    // Which axis (if any) is not spatial.
    let dropped: Option<usize> = if let Some(dirs) = &h.directions {
        let nones: Vec<usize> = (0..dimension).filter(|&a| dirs[a].is_none()).collect();
        if nones.len() + 3 != dimension {
            return Err(Error::unsupported(
                name,
                format!(
                    "{} of {dimension} axes have a space direction; exactly 3 spatial axes are needed",
                    dimension - nones.len()
                ),
            ));
        }
        nones.first().copied()
    } else if dimension == 4 {
        let nan_spacing = h.spacings.as_ref().and_then(|s| one_index(s.iter().map(|x| x.is_nan())));
        let kind_marked = h.kinds.as_ref().filter(|k| k.len() == 4).and_then(|k| {
            one_index(k.iter().map(|k| !matches!(k.as_str(), "domain" | "space" | "time" | "???" | "none")))
        });
        nan_spacing.or(kind_marked).or_else(|| h.sizes.iter().position(|&n| n == 1))
    } else {
        None
    };
    if dimension == 4 {
        let a = dropped.ok_or_else(|| {
            Error::unsupported(
                name,
                format!("4-D data of sizes {:?}: vector and time-series volumes are not supported", h.sizes),
            )
        })?;
        if h.sizes[a] != 1 {
            return Err(Error::unsupported(
                name,
                format!(
                    "axis {a} is not spatial and has {} samples (sizes {:?}): vector and 4-D volumes are not supported",
                    h.sizes[a], h.sizes
                ),
            ));
        }
    }
    let spatial: Vec<usize> = (0..dimension).filter(|&a| Some(a) != dropped).collect();
    let dims = [h.sizes[spatial[0]], h.sizes[spatial[1]], h.sizes[spatial[2]]];

    if let (Some(space), Some(dirs)) = (h.space, &h.directions) {
        let s = space.lps_signs();
        let mut linear = Matrix3::zeros();
        for (c, &a) in spatial.iter().enumerate() {
            let d = dirs[a].unwrap_or([0.0; 3]);
            for r in 0..3 {
                linear[(r, c)] = s[r] * d[r];
            }
        }
        let o = h.origin.unwrap_or_else(|| {
            h.warnings.push("the header has no \"space origin\"; origin 0 assumed".to_string());
            [0.0; 3]
        });
        let origin_lps = [s[0] * o[0], s[1] * o[1], s[2] * o[2]];
        return Ok(Geometry {
            dims,
            lps_from_index: Transform::from_linear_translation(linear, origin_lps),
            source: GeometrySource::NrrdSpace,
        });
    }
    let scale = if let Some(sp) = &h.spacings {
        let v = [sp[spatial[0]], sp[spatial[1]], sp[spatial[2]]];
        if v.iter().any(|x| x.is_nan()) {
            return Err(Error::invalid(name, format!("a spatial axis has spacing nan: {sp:?}")));
        }
        v
    } else {
        h.warnings.push("the header has neither a space nor spacings; unit spacing assumed".to_string());
        [1.0; 3]
    };
    Ok(Geometry {
        dims,
        lps_from_index: Transform::from_scale_translation(scale, [0.0; 3]),
        source: GeometrySource::NrrdSpacings,
    })
}

/// The index of the only `true`, if exactly one.
fn one_index(it: impl Iterator<Item = bool>) -> Option<usize> {
    let hits: Vec<usize> = it.enumerate().filter(|(_, b)| *b).map(|(i, _)| i).collect();
    if hits.len() == 1 { Some(hits[0]) } else { None }
}

// ---------------------------------------------------------------------------------------------
// Data

fn read_from<R: BufRead>(
    name: &Path,
    mut r: R,
    total_len: u64,
    base_dir: Option<&Path>,
    opts: &mut LoadOptions,
) -> Result<Volume> {
    let (lines, header_bytes) = read_header_lines(name, &mut r)?;
    let mut h = parse_header(name, &lines)?;
    let g = geometry(name, &mut h)?;
    let out_type = h.stored.unscaled();
    preflight_size(name, g.dims, out_type.bytes(), opts.max_voxel_bytes)?;
    let n = check_allocation(name, g.dims, out_type.bytes(), opts.max_voxel_bytes)?;
    let need = (n as u64).checked_mul(h.stored.bytes() as u64).ok_or_else(|| {
        Error::new(
            name,
            ErrorKind::TooLarge {
                what: format!("dims {:?}", g.dims),
                bytes: n as u128 * h.stored.bytes() as u128,
                limit: opts.max_voxel_bytes,
            },
        )
    })?;

    let data = if let Some(df) = &h.data_file {
        let Some(base) = base_dir else {
            return Err(Error::unsupported(name, format!("detached data file {df:?} cannot be read from memory")));
        };
        let data_path = base.join(df);
        // A pipe would block and a device such as /dev/zero never ends: refused before it is opened.
        crate::check_regular_file(&data_path)?;
        let file = File::open(&data_path).map_err(|e| Error::io(&data_path, e))?;
        let len = file.metadata().map_err(|e| Error::io(&data_path, e))?.len();
        decode_payload(&data_path, BufReader::new(file), len, &h, n, need, opts)?
    } else {
        decode_payload(name, r, total_len.saturating_sub(header_bytes), &h, n, need, opts)?
    };

    let mut volume = Volume::new(name, g.dims, data, g.lps_from_index, g.source)?;
    let mut warnings = std::mem::take(&mut h.warnings);
    warnings.append(&mut volume.metadata.warnings); // the geometry's, from Volume::new
    volume.metadata = Metadata {
        description: h.content.clone(),
        value_units: h.sample_units.clone().filter(|s| !s.is_empty()),
        warnings,
        ..Metadata::default()
    };
    Ok(volume)
}

/// Refuses sizes whose byte count overflows even u128 (three huge `usize`s), which
/// [`check_allocation`] cannot yet compute; everything else is left to it.
fn preflight_size(name: &Path, dims: [usize; 3], bytes_per_sample: usize, limit: u64) -> Result<()> {
    let bytes = dims.iter().try_fold(bytes_per_sample as u128, |acc, &d| acc.checked_mul(d as u128));
    match bytes {
        Some(_) => Ok(()),
        None => Err(Error::new(name, ErrorKind::TooLarge { what: format!("dims {dims:?}"), bytes: u128::MAX, limit })),
    }
}

/// Decodes the `n` samples (`need` stored bytes) that start at the reader's position, which has
/// `len` bytes left. `path` is the file that holds the data (for errors).
///
/// The reader is cut at those `len` bytes, so every skip and scan below ends with the file, even
/// one that grows or claims a line skip longer than itself.
fn decode_payload<R: BufRead>(
    path: &Path,
    r: R,
    mut len: u64,
    h: &Header,
    n: usize,
    need: u64,
    opts: &mut LoadOptions,
) -> Result<VoxelData> {
    let mut r = r.take(len);
    for i in 0..h.line_skip {
        let (skipped, ended) = skip_line(&mut r).map_err(|e| Error::io(path, e))?;
        if !ended {
            return Err(Error::truncated(
                path,
                format!("the data end within line skip ({i} of {} lines skipped)", h.line_skip),
            ));
        }
        len = len.saturating_sub(skipped);
    }
    let byte_skip = if h.byte_skip == -1 {
        len.checked_sub(need).ok_or_else(|| {
            Error::truncated(path, format!("{len} bytes of data for the {need} bytes that {n} samples need"))
        })?
    } else {
        h.byte_skip as u64
    };
    // Cheap plausibility checks on the encoded length, before any voxel buffer is allocated.
    let enough = match h.encoding {
        Encoding::Raw => len >= byte_skip.saturating_add(need),
        Encoding::Gzip => {
            len.saturating_mul(MAX_DEFLATE_RATIO).saturating_add(1 << 16) >= need.saturating_add(byte_skip)
        }
        Encoding::Hex => len >= byte_skip.saturating_add(need.saturating_mul(2)),
        Encoding::Ascii => len >= byte_skip.saturating_add((n as u64).saturating_mul(2).saturating_sub(1)),
    };
    if !enough {
        return Err(Error::truncated(
            path,
            format!("{len} bytes of {:?} data cannot hold {n} samples of {} bytes", h.encoding, h.stored.bytes()),
        ));
    }
    let data = match h.encoding {
        Encoding::Raw => {
            skip_bytes(path, &mut r, byte_skip, "byte skip")?;
            decode_binary(path, &mut r, h, n, opts)?
        }
        Encoding::Gzip => {
            let mut gz = BufReader::new(MultiGzDecoder::new(r));
            skip_bytes(path, &mut gz, byte_skip, "byte skip (decompressed)")?;
            decode_binary(path, &mut gz, h, n, opts)?
        }
        Encoding::Hex => {
            skip_bytes(path, &mut r, byte_skip, "byte skip")?;
            decode_binary(path, &mut HexReader { inner: r }, h, n, opts)?
        }
        Encoding::Ascii => {
            skip_bytes(path, &mut r, byte_skip, "byte skip")?;
            decode_ascii(path, &mut r, h.stored, n, opts)?
        }
    };
    Ok(data)
}

/// Skips one line, through its `\n`; returns the bytes skipped and whether the `\n` was there (not the end of the
/// input first).
fn skip_line(r: &mut impl BufRead) -> io::Result<(u64, bool)> {
    let mut skipped = 0u64;
    loop {
        let buf = match r.fill_buf() {
            Ok(b) => b,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if buf.is_empty() {
            return Ok((skipped, false));
        }
        let (used, ended) = buf.iter().position(|&b| b == b'\n').map_or((buf.len(), false), |i| (i + 1, true));
        r.consume(used);
        skipped += used as u64;
        if ended {
            return Ok((skipped, true));
        }
    }
}

fn skip_bytes(path: &Path, r: &mut impl Read, count: u64, what: &str) -> Result<()> {
    let skipped = io::copy(&mut r.by_ref().take(count), &mut io::sink()).map_err(|e| data_error(path, e))?;
    if skipped < count {
        return Err(Error::truncated(path, format!("the data end within the {what} of {count} bytes")));
    }
    Ok(())
}

/// Errors while decoding samples: a corrupt gzip stream is invalid data, not an I/O failure.
fn data_error(path: &Path, e: io::Error) -> Error {
    match e.kind() {
        io::ErrorKind::InvalidInput | io::ErrorKind::InvalidData => Error::invalid(path, format!("corrupt data: {e}")),
        _ => Error::io(path, e),
    }
}

fn decode_binary(path: &Path, r: &mut impl Read, h: &Header, n: usize, opts: &mut LoadOptions) -> Result<VoxelData> {
    let size = h.stored.bytes();
    let total = (n * size) as u64;
    let big = h.big_endian;
    let mut out = output_buffer(path, h.stored.unscaled(), n)?;
    let mut buf = vec![0u8; CHUNK_BYTES.min(n * size)];
    let mut done = 0usize;
    opts.report(path, "reading", 0, total)?;
    while done < n {
        let count = (n - done).min(CHUNK_BYTES / size);
        let bytes = &mut buf[..count * size];
        let got = crate::read_up_to(r, bytes).map_err(|e| data_error(path, e))?;
        if got < bytes.len() {
            let have = done as u64 * size as u64 + got as u64;
            return Err(Error::truncated(path, format!("the data end after {have} of {total} bytes")));
        }
        sample::with_stored_type!(h.stored, T => out.extend_from(sample::decode::<T>(bytes, big)));
        done += count;
        opts.report(path, "reading", (done * size) as u64, total)?;
    }
    Ok(out)
}

/// Room for `n` samples of `t`, allocated fallibly (an error naming `path`, never an abort).
fn output_buffer(path: &Path, t: SampleType, n: usize) -> Result<VoxelData> {
    VoxelData::try_empty(path, t, n, &format!("{n} samples of {}", t.name()))
}

/// Pushes one ASCII token onto `out`; `None` when it is not a value of the stored type.
fn push_text(out: &mut VoxelData, stored: StoredType, t: &str) -> Option<()> {
    match (out, stored) {
        (VoxelData::U8(v), _) => v.push(t.parse().ok()?),
        (VoxelData::I16(v), StoredType::I8) => v.push(i16::from(t.parse::<i8>().ok()?)),
        (VoxelData::I16(v), _) => v.push(t.parse().ok()?),
        (VoxelData::U16(v), _) => v.push(t.parse().ok()?),
        (VoxelData::F32(v), StoredType::F32) => v.push(t.parse().ok()?),
        (VoxelData::F32(v), StoredType::I32 | StoredType::I64) => v.push(t.parse::<i64>().ok()? as f32),
        (VoxelData::F32(v), StoredType::U32 | StoredType::U64) => v.push(t.parse::<u64>().ok()? as f32),
        (VoxelData::F32(v), _) => v.push(t.parse::<f64>().ok()? as f32),
    }
    Some(())
}

/// Whitespace- (or comma-) separated numbers.
fn decode_ascii(
    path: &Path,
    r: &mut impl BufRead,
    stored: StoredType,
    n: usize,
    opts: &mut LoadOptions,
) -> Result<VoxelData> {
    const MAX_TOKEN: usize = 64;
    let mut out = output_buffer(path, stored.unscaled(), n)?;
    let mut tok = String::new();
    let mut count = 0usize;
    let mut finish_token = |tok: &mut String, count: &mut usize| -> Result<()> {
        if tok.is_empty() || *count >= n {
            tok.clear();
            return Ok(());
        }
        push_text(&mut out, stored, tok).ok_or_else(|| {
            Error::invalid(path, format!("ASCII sample {} is {tok:?}, not a {stored:?} value", *count + 1))
        })?;
        *count += 1;
        tok.clear();
        Ok(())
    };
    let mut last_report = 0usize;
    while count < n {
        let buf = r.fill_buf().map_err(|e| Error::io(path, e))?;
        if buf.is_empty() {
            break;
        }
        let used = buf.len();
        for &b in buf {
            if b.is_ascii_whitespace() || b == b',' {
                finish_token(&mut tok, &mut count)?;
            } else {
                if tok.len() >= MAX_TOKEN {
                    return Err(Error::invalid(
                        path,
                        format!("ASCII sample {} is longer than {MAX_TOKEN} characters", count + 1),
                    ));
                }
                tok.push(char::from(b));
            }
        }
        r.consume(used);
        if count - last_report >= CHUNK_BYTES / 8 {
            last_report = count;
            opts.report(path, "reading", count as u64, n as u64)?;
        }
    }
    finish_token(&mut tok, &mut count)?;
    if count < n {
        return Err(Error::truncated(path, format!("the ASCII data end after {count} of {n} samples")));
    }
    opts.report(path, "reading", n as u64, n as u64)?;
    Ok(out)
}

/// Decodes `hex` encoding: pairs of hex digits, whitespace ignored.
struct HexReader<R> {
    inner: R,
}

impl<R: BufRead> Read for HexReader<R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        let mut written = 0;
        let mut high: Option<u8> = None;
        while written < out.len() {
            let buf = self.inner.fill_buf()?;
            let Some(&c) = buf.first() else {
                if high.is_some() {
                    return Err(io::Error::new(io::ErrorKind::InvalidData, "odd number of hex digits"));
                }
                break;
            };
            self.inner.consume(1);
            if c.is_ascii_whitespace() {
                continue;
            }
            let v = match c {
                b'0'..=b'9' => c - b'0',
                b'a'..=b'f' => c - b'a' + 10,
                b'A'..=b'F' => c - b'A' + 10,
                _ => {
                    return Err(io::Error::new(
                        io::ErrorKind::InvalidData,
                        format!("{:?} is not a hex digit", char::from(c)),
                    ));
                }
            };
            match high.take() {
                None => high = Some(v),
                Some(hi) => {
                    out[written] = (hi << 4) | v;
                    written += 1;
                }
            }
        }
        Ok(written)
    }
}
