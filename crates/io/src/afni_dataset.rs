//! AFNI datasets: a `.HEAD` file of attributes beside a `.BRIK` (or `.BRIK.gz`) of samples, what AFNI's programs
//! write by default (`anat+orig`, `stats+tlrc`, `3dQwarp`'s `…_WARP+tlrc`): [`read()`] reads one sub-brick as a
//! volume, [`read_warp`] reads a `3dQwarp` warp as a pull-back displacement field.
//!
//! # The format
//!
//! The `.HEAD` file is text: a list of attributes, each
//!
//! ```text
//! type = integer-attribute        (or float-attribute, string-attribute)
//! name = DATASET_DIMENSIONS
//! count = 5
//!  47 54 43 0 0
//! ```
//!
//! a string's value being a single quote then `count` characters, `~` standing for a NUL (it ends each label of
//! `BRICK_LABS`). The attributes read (R. W. Cox, "AFNI .HEAD file attributes", `README.attributes`; nibabel's
//! `brikhead.py`):
//!
//! | attribute | what |
//! |---|---|
//! | `DATASET_RANK` | 3, then the number of sub-bricks |
//! | `DATASET_DIMENSIONS` | the voxels along i, j, k |
//! | `BRICK_TYPES` | each sub-brick's type: 0 byte (u8), 1 short (i16), 3 float (f32); absent: all short |
//! | `BRICK_FLOAT_FACS` | each sub-brick's scale factor; 0 (or absent) none: the value is factor × stored |
//! | `BYTEORDER_STRING` | `LSB_FIRST` or `MSB_FIRST`; absent: the writer's own order, taken as `LSB_FIRST` with a warning |
//! | `BRICK_LABS` | the sub-bricks' labels, `~`-separated |
//! | `ORIENT_SPECIFIC`, `ORIGIN`, `DELTA` | each axis's direction (0 R→L, 1 L→R, 2 P→A, 3 A→P, 4 I→S, 5 S→I), voxel 0's coordinate along it and the signed step |
//! | `IJK_TO_DICOM_REAL` | the 3×4 matrix from (i, j, k) to DICOM coordinates, which an oblique dataset needs |
//!
//! The `.BRIK` holds the sub-bricks one after the other, each i fastest, then j, then k.
//!
//! # Geometry
//!
//! AFNI's coordinates are DICOM's: x grows to the left, y to the back, z up, in mm: warpbench's LPS, with no flip.
//! The matrix is `IJK_TO_DICOM_REAL` when the file has it (as nibabel reads it); without it (AFNI before 2007), axis a
//! adds `DELTA[a]` per voxel to the DICOM coordinate its `ORIENT_SPECIFIC` code names, starting from `ORIGIN[a]`.
//! A dataset whose `IJK_TO_DICOM_REAL` differs from that cardinal grid is oblique: AFNI's programs work on it in the
//! cardinal grid (its `3dWarp -deoblique`), so a warp on an oblique grid is refused.
//!
//! # Warps
//!
//! `3dQwarp` writes its warp as a dataset of three float sub-bricks labelled `x_delta`, `y_delta` and `z_delta`
//! (AFNI's `IW3D_to_dataset`): at each voxel centre x of the base's grid, the displacement in DICOM mm to the
//! source's point, which `3dNwarpApply` reads at x + D(x). That is warpbench's pull-back, in LPS as it stands. A warp
//! saved as NIfTI (`-prefix x_WARP.nii.gz`) is the same three sub-bricks, told apart by AFNI's extension
//! ([`crate::nifti::afni_extension`]).
//!
//! # Robustness
//!
//! The `.HEAD` is read up to [`MAX_HEAD_BYTES`]; every count is bounded by what is left of it, so no attribute
//! allocates more than the file holds. The sizes are checked before the samples are allocated
//! ([`volume::check_allocation`]), and the sub-brick read must end inside the `.BRIK` (or within what gzip can inflate
//! from a `.BRIK.gz`). A `.BRIK` compressed otherwise (`.bz2`, `.Z`, `.zst`, AFNI's other choices) is refused by
//! name. Errors name the file at fault, the `.HEAD` or the `.BRIK`.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use flate2::read::MultiGzDecoder;
use nalgebra::Matrix3;

use crate::displacement::{FieldDirection, FieldFormat, FieldSource, ReadField};
use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::nifti::DisplacementField;
use crate::options::LoadOptions;
use crate::sample::{self, StoredType, rescale_samples};
use crate::stream::{MAX_DEFLATE_RATIO, Source, fill};
use crate::volume::{self, GeometrySource, Rescale, Volume, VoxelData};

/// The largest `.HEAD` read: AFNI's own are a few kB, with a long history note a few hundred.
pub const MAX_HEAD_BYTES: u64 = 16 << 20;

pub use crate::nifti::afni_extension::WARP_LABELS;

/// Bytes read between progress reports.
const CHUNK_BYTES: usize = 4 << 20;

/// The suffixes of an AFNI dataset's files (case ignored), the compressions AFNI writes among them.
const SUFFIXES: [(&str, Part); 6] = [
    (".head", Part::Head),
    (".brik", Part::Brik(Packing::Plain)),
    (".brik.gz", Part::Brik(Packing::Gzip)),
    (".brik.bz2", Part::Brik(Packing::Other("bzip2 (bunzip2)"))),
    (".brik.z", Part::Brik(Packing::Other("compress (uncompress)"))),
    (".brik.zst", Part::Brik(Packing::Other("zstd (unzstd)"))),
];

/// Which file of a dataset a name is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    Head,
    Brik(Packing),
}

/// How a `.BRIK` is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Packing {
    Plain,
    Gzip,
    /// A compression this reader does not inflate, with the command that does.
    Other(&'static str),
}

/// AFNI's views, the last part of a dataset's name (`anat+orig`).
const VIEWS: [&str; 3] = ["+orig", "+acpc", "+tlrc"];

/// Whether `path` names an AFNI dataset: one of its files (`.HEAD`, `.BRIK`, `.BRIK.gz`, …; case ignored), or, as
/// AFNI's programs take it, the dataset's bare name (`anat+orig`, `anat+orig.`) when that is not a file itself, either
/// perhaps with a sub-brick selector (`anat+orig[2]`, `anat+orig.HEAD[$]`): what [`crate::Format::detect`] goes by.
#[must_use]
pub fn has_afni_name(path: &Path) -> bool {
    split_name(path).is_some_and(|n| (n.part.is_some() && n.selector.is_none()) || !path.is_file())
}

/// Whether `path` names an AFNI dataset ([`has_afni_name`]) whose header says it is a `3dQwarp` warp
/// ([`Header::is_warp`]).
///
/// # Errors
/// The header is missing or malformed (named).
pub fn is_warp_file(path: &Path) -> Result<bool> {
    if !has_afni_name(path) {
        return Ok(false);
    }
    let Some(name) = split_name(path) else { return Ok(false) };
    let head = path.with_file_name(format!("{}.HEAD", name.stem));
    Ok(Header::read(&head)?.is_warp())
}

/// A dataset's name taken apart: `stem` without a suffix (`anat+orig`), which file the name is (none for the bare
/// name) and the sub-brick selector's text between its brackets.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Name {
    stem: String,
    part: Option<Part>,
    selector: Option<String>,
}

fn split_name(path: &Path) -> Option<Name> {
    let mut name = path.file_name()?.to_string_lossy().into_owned();
    let mut selector = None;
    if name.ends_with(']')
        && let Some(open) = name.rfind('[')
    {
        selector = Some(name[open + 1..name.len() - 1].to_string());
        name.truncate(open);
    }
    let lower = name.to_ascii_lowercase();
    let suffix = SUFFIXES
        .iter()
        .filter(|(suffix, _)| lower.ends_with(suffix) && lower.len() > suffix.len())
        .max_by_key(|(suffix, _)| suffix.len());
    if let Some(&(suffix, part)) = suffix {
        return Some(Name { stem: name[..name.len() - suffix.len()].to_string(), part: Some(part), selector });
    }
    let stem = name.strip_suffix('.').unwrap_or(&name);
    let viewed = VIEWS.iter().any(|v| stem.len() > v.len() && stem.ends_with(v));
    viewed.then(|| Name { stem: stem.to_string(), part: None, selector })
}

/// The sub-brick a selector names: `N`, or `$` for the last; AFNI's lists, ranges and labels are refused.
fn sub_brick(head: &Path, selector: &str, bricks: usize) -> Result<usize> {
    let t = match selector.trim() {
        "$" => bricks - 1,
        n => n.parse::<usize>().map_err(|_| {
            Error::unsupported(
                head,
                format!(
                    "sub-brick selector [{selector}]: one sub-brick is read, [N] or [$] (the last); a list, a \
                     range or a label is not"
                ),
            )
        })?,
    };
    if t >= bricks {
        return Err(Error::invalid(head, format!("sub-brick {t} is out of range: the dataset has {bricks}")));
    }
    Ok(t)
}

/// The two files of the dataset `path` names (either of them).
#[derive(Clone, Debug)]
struct Files {
    head: PathBuf,
    brik: PathBuf,
    /// Whether the `.BRIK` is gzip-compressed (the only compression read).
    gzip: bool,
    /// The sub-brick selector the name ends with (`[2]`), if any.
    selector: Option<String>,
}

impl Files {
    fn of(path: &Path) -> Result<Self> {
        let Some(Name { stem, part, selector }) = split_name(path) else {
            return Err(Error::invalid(path, "not an AFNI dataset: its name ends neither in .HEAD nor in .BRIK"));
        };
        let folder = path.parent().unwrap_or_else(|| Path::new(""));
        let head = match (part, &selector) {
            (Some(Part::Head), None) => path.to_path_buf(),
            _ => folder.join(format!("{stem}.HEAD")),
        };
        if !head.is_file() {
            return Err(Error::invalid(path, format!("an AFNI dataset's header {} is not beside it", head.display())));
        }
        let candidates = match part {
            Some(Part::Brik(packing)) if selector.is_none() => vec![(path.to_path_buf(), packing)],
            Some(Part::Brik(packing)) => {
                let brik = path.with_file_name(path.file_name().map_or_else(String::new, |n| {
                    let n = n.to_string_lossy();
                    n[..n.rfind('[').unwrap_or(n.len())].to_string()
                }));
                vec![(brik, packing)]
            }
            Some(Part::Head) | None => SUFFIXES
                .iter()
                .filter_map(|&(suffix, p)| match p {
                    Part::Brik(packing) => Some((folder.join(format!("{stem}{}", brik_suffix(suffix))), packing)),
                    Part::Head => None,
                })
                .collect(),
        };
        let selector = selector.filter(|s| !s.is_empty());
        let Some((brik, packing)) = candidates.into_iter().find(|(p, _)| p.is_file()) else {
            return Err(Error::invalid(
                &head,
                format!("the dataset's samples are missing: no {stem}.BRIK (or .BRIK.gz) beside it"),
            ));
        };
        if let Packing::Other(how) = packing {
            return Err(Error::unsupported(
                &brik,
                format!("a .BRIK compressed with {how}: decompress it, or gzip it, first"),
            ));
        }
        Ok(Self { head, brik, gzip: packing == Packing::Gzip, selector })
    }
}

/// `.brik.gz` as AFNI spells it: `.BRIK.gz`.
fn brik_suffix(lower: &str) -> String {
    let (brik, rest) = lower.split_at(5);
    format!("{}{rest}", brik.to_ascii_uppercase())
}

/// One attribute's value.
#[derive(Clone, Debug, PartialEq)]
enum Value {
    Integers(Vec<i64>),
    Floats(Vec<f64>),
    Text(String),
}

/// A `.HEAD` file's attributes, by name.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    path: PathBuf,
    attributes: BTreeMap<String, Value>,
}

impl Header {
    /// Reads and parses the `.HEAD` file at `path`.
    ///
    /// # Errors
    /// The file cannot be read, is larger than [`MAX_HEAD_BYTES`], or an attribute is malformed (named).
    pub fn read(path: &Path) -> Result<Self> {
        let meta = crate::files::check_regular_file(path)?;
        if meta.len() > MAX_HEAD_BYTES {
            return Err(Error::invalid(
                path,
                format!("{} bytes: an AFNI header is at most {MAX_HEAD_BYTES} bytes", meta.len()),
            ));
        }
        let mut bytes = Vec::new();
        File::open(path)
            .and_then(|f| f.take(MAX_HEAD_BYTES).read_to_end(&mut bytes))
            .map_err(|e| Error::io(path, e))?;
        Self::parse(path, &bytes)
    }

    /// Parses the text of a `.HEAD` file; `path` names it in errors.
    ///
    /// # Errors
    /// An attribute is malformed: its `type`, `name` or `count` line, or fewer values than its count.
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Self> {
        let mut c = Cursor { bytes, at: 0 };
        let mut attributes = BTreeMap::new();
        let mut last = String::from("the start of the file");
        while c.skip_space() {
            let bad = |what: String| Error::invalid(path, format!("after attribute {last}: {what}"));
            let kind = c.field("type").map_err(bad)?;
            let name = c.field("name").map_err(bad)?;
            let count = c.field("count").map_err(bad)?;
            let bad = |what: String| Error::invalid(path, format!("attribute {name}: {what}"));
            let count: usize = count.parse().map_err(|_| bad(format!("count '{count}' is not a whole number")))?;
            if count > bytes.len() - c.at {
                return Err(bad(format!("count {count} is more than the {} bytes left", bytes.len() - c.at)));
            }
            let value = match kind.as_str() {
                "integer-attribute" => Value::Integers(c.numbers(count).map_err(bad)?),
                "float-attribute" => Value::Floats(c.numbers(count).map_err(bad)?),
                "string-attribute" => Value::Text(c.text(count).map_err(bad)?),
                other => return Err(bad(format!("type '{other}' is not integer-, float- or string-attribute"))),
            };
            attributes.insert(name.clone(), value);
            last = name;
        }
        Ok(Self { path: path.to_path_buf(), attributes })
    }

    fn integers(&self, name: &str) -> Result<Option<&[i64]>> {
        match self.attributes.get(name) {
            None => Ok(None),
            Some(Value::Integers(v)) => Ok(Some(v)),
            Some(_) => Err(Error::invalid(&self.path, format!("attribute {name} is not an integer-attribute"))),
        }
    }

    fn floats(&self, name: &str) -> Result<Option<&[f64]>> {
        match self.attributes.get(name) {
            None => Ok(None),
            Some(Value::Floats(v)) => Ok(Some(v)),
            Some(_) => Err(Error::invalid(&self.path, format!("attribute {name} is not a float-attribute"))),
        }
    }

    fn text(&self, name: &str) -> Option<&str> {
        match self.attributes.get(name) {
            Some(Value::Text(t)) => Some(t),
            _ => None,
        }
    }

    /// At least `n` values of the attribute `name`, which must be there.
    fn required<'a, T>(
        &'a self,
        name: &str,
        n: usize,
        get: fn(&'a Self, &str) -> Result<Option<&'a [T]>>,
    ) -> Result<&'a [T]> {
        match get(self, name)? {
            Some(v) if v.len() >= n => Ok(&v[..n]),
            Some(v) => Err(Error::invalid(&self.path, format!("attribute {name} has {} values, {n} needed", v.len()))),
            None => Err(Error::invalid(&self.path, format!("attribute {name} is missing: not an AFNI dataset header"))),
        }
    }

    /// The voxels along i, j, k and the number of sub-bricks.
    fn shape(&self) -> Result<([usize; 3], usize)> {
        let rank = self.required("DATASET_RANK", 2, Self::integers)?;
        if rank[0] != 3 {
            return Err(Error::unsupported(
                &self.path,
                format!("DATASET_RANK gives {} dimensions; 3 are read", rank[0]),
            ));
        }
        let n = self.required("DATASET_DIMENSIONS", 3, Self::integers)?;
        if n.iter().any(|&d| d < 1) || rank[1] < 1 {
            return Err(Error::invalid(
                &self.path,
                format!("dimensions {n:?} and {} sub-bricks: each must be at least 1", rank[1]),
            ));
        }
        let size =
            |v: i64| usize::try_from(v).map_err(|_| Error::invalid(&self.path, format!("size {v} is too large")));
        Ok(([size(n[0])?, size(n[1])?, size(n[2])?], size(rank[1])?))
    }

    /// Each sub-brick's stored type (`BRICK_TYPES`; absent, all short).
    fn brick_types(&self, bricks: usize) -> Result<Vec<StoredType>> {
        let Some(codes) = self.integers("BRICK_TYPES")? else {
            return Ok(vec![StoredType::I16; bricks]);
        };
        let codes = self.required("BRICK_TYPES", bricks, Self::integers).map_err(|_| {
            Error::invalid(&self.path, format!("BRICK_TYPES has {} values for {bricks} sub-bricks", codes.len()))
        })?;
        codes
            .iter()
            .enumerate()
            .map(|(t, &code)| match code {
                0 => Ok(StoredType::U8),
                1 => Ok(StoredType::I16),
                3 => Ok(StoredType::F32),
                _ => {
                    let what = match code {
                        2 => "int",
                        4 => "double",
                        5 => "complex",
                        6 => "rgb",
                        7 => "rgba",
                        _ => "not an AFNI type code",
                    };
                    Err(Error::unsupported(
                        &self.path,
                        format!(
                            "sub-brick {t} has type {code} ({what}); readable: 0 byte (u8), 1 short (i16), 3 float \
                             (f32)"
                        ),
                    ))
                }
            })
            .collect()
    }

    /// Sub-brick `t`'s scale factor, `None` when there is none (0, 1 or absent).
    fn factor(&self, t: usize) -> Result<Option<f64>> {
        let f = self.floats("BRICK_FLOAT_FACS")?.and_then(|v| v.get(t).copied()).unwrap_or(0.0);
        if !f.is_finite() {
            return Err(Error::invalid(&self.path, format!("sub-brick {t}'s scale factor is {f}")));
        }
        Ok((f != 0.0 && f.to_bits() != 1f64.to_bits()).then_some(f))
    }

    /// Whether the samples are big-endian, and the warning when the header does not say.
    fn big_endian(&self) -> Result<(bool, Option<String>)> {
        match self.text("BYTEORDER_STRING") {
            Some("MSB_FIRST") => Ok((true, None)),
            Some("LSB_FIRST") => Ok((false, None)),
            Some(other) => {
                Err(Error::invalid(&self.path, format!("BYTEORDER_STRING is '{other}', not LSB_FIRST or MSB_FIRST")))
            }
            None => Ok((
                false,
                Some(
                    "the header has no BYTEORDER_STRING: the samples are in the order of the machine that wrote \
                     them, taken as LSB_FIRST (little-endian, as on x86 and ARM)"
                        .to_string(),
                ),
            )),
        }
    }

    /// The sub-bricks' labels (`BRICK_LABS`), as many as there are, `None` where the file gives none.
    #[must_use]
    pub fn labels(&self) -> Vec<String> {
        self.text("BRICK_LABS").map(|t| t.split('~').map(str::to_string).collect()).unwrap_or_default()
    }

    /// Whether the first three sub-bricks are labelled as a `3dQwarp` warp's ([`WARP_LABELS`]).
    #[must_use]
    pub fn is_warp(&self) -> bool {
        crate::nifti::afni_extension::are_warp_labels(&self.labels())
    }

    /// The grid from `ORIENT_SPECIFIC`, `ORIGIN` and `DELTA` (module docs, "Geometry").
    fn cardinal(&self) -> Result<Transform<Lps, Index>> {
        let orient = self.required("ORIENT_SPECIFIC", 3, Self::integers)?;
        let origin = self.required("ORIGIN", 3, Self::floats)?;
        let delta = self.required("DELTA", 3, Self::floats)?;
        let mut rows = [None::<usize>; 3];
        for (a, &code) in orient.iter().enumerate() {
            let row = match code {
                0..=5 => (code / 2) as usize,
                _ => {
                    return Err(Error::invalid(&self.path, format!("ORIENT_SPECIFIC code {code} is not 0 to 5")));
                }
            };
            if rows[row].replace(a).is_some() {
                return Err(Error::invalid(
                    &self.path,
                    format!("ORIENT_SPECIFIC {orient:?} gives two axes one direction"),
                ));
            }
        }
        let axis_of = |row: usize| rows[row].unwrap_or(0); // each row was given an axis above
        let linear = Matrix3::from_fn(|r, c| if axis_of(r) == c { delta[c] } else { 0.0 });
        Ok(Transform::from_linear_translation(linear, std::array::from_fn(|r| origin[axis_of(r)])))
    }

    /// The dataset's grid (module docs, "Geometry") and whether it is oblique.
    fn grid(&self) -> Result<(Transform<Lps, Index>, bool)> {
        let cardinal = self.cardinal();
        let Some(real) = self.floats("IJK_TO_DICOM_REAL")? else {
            return Ok((cardinal?, false));
        };
        if real.len() < 12 {
            return Err(Error::invalid(&self.path, format!("IJK_TO_DICOM_REAL has {} values, 12 needed", real.len())));
        }
        let linear = Matrix3::from_fn(|r, c| real[4 * r + c]);
        let real = Transform::from_linear_translation(linear, [real[3], real[7], real[11]]);
        let oblique = cardinal.map_or(true, |c| {
            c.rows().iter().flatten().zip(real.rows().iter().flatten()).any(|(a, b)| (a - b).abs() > 1e-3)
        });
        Ok((real, oblique))
    }
}

/// A cursor over the `.HEAD` text.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    /// Skips white space; whether anything is left.
    fn skip_space(&mut self) -> bool {
        while self.at < self.bytes.len() && self.bytes[self.at].is_ascii_whitespace() {
            self.at += 1;
        }
        self.at < self.bytes.len()
    }

    /// The next word, up to white space.
    fn word(&mut self) -> &str {
        self.skip_space();
        let start = self.at;
        while self.at < self.bytes.len() && !self.bytes[self.at].is_ascii_whitespace() && self.bytes[self.at] != b'=' {
            self.at += 1;
        }
        std::str::from_utf8(&self.bytes[start..self.at]).unwrap_or("(not text)")
    }

    /// `key = value`: the value.
    fn field(&mut self, key: &str) -> std::result::Result<String, String> {
        let got = self.word().to_string();
        if got != key {
            return Err(format!("expected '{key} =', found '{got}'"));
        }
        self.skip_space();
        if self.bytes.get(self.at) != Some(&b'=') {
            return Err(format!("expected '=' after '{key}'"));
        }
        self.at += 1;
        Ok(self.word().to_string())
    }

    /// `count` numbers, separated by white space.
    fn numbers<T: std::str::FromStr>(&mut self, count: usize) -> std::result::Result<Vec<T>, String> {
        let mut out = Vec::with_capacity(count);
        for k in 0..count {
            let w = self.word();
            out.push(w.parse().map_err(|_| {
                if w.is_empty() {
                    format!("the file ends after {k} of {count} values")
                } else {
                    format!("value {} '{w}' is not a number", k + 1)
                }
            })?);
        }
        Ok(out)
    }

    /// A string: a quote, then `count` characters, the NULs (`~`) at its end dropped.
    fn text(&mut self, count: usize) -> std::result::Result<String, String> {
        self.skip_space();
        if self.bytes.get(self.at) != Some(&b'\'') {
            return Err("a string-attribute's value does not start with a single quote".to_string());
        }
        self.at += 1;
        let end = self.at + count;
        let Some(raw) = self.bytes.get(self.at..end) else {
            return Err(format!("the file ends inside its {count} characters"));
        };
        self.at = end;
        let text = String::from_utf8_lossy(raw);
        Ok(text.trim_end_matches(['~', '\0']).to_string())
    }
}

/// A dataset's header and files, opened.
struct Dataset {
    files: Files,
    header: Header,
    dims: [usize; 3],
    types: Vec<StoredType>,
}

impl Dataset {
    fn open(path: &Path) -> Result<Self> {
        let files = Files::of(path)?;
        let header = Header::read(&files.head)?;
        let (dims, bricks) = header.shape()?;
        let types = header.brick_types(bricks)?;
        Ok(Self { files, header, dims, types })
    }

    /// Reads sub-brick `t`'s stored bytes, checked against the `.BRIK`'s length before anything is allocated.
    fn brick_bytes(&self, t: usize, opts: &mut LoadOptions) -> Result<Vec<u8>> {
        let brik = &self.files.brik;
        let stored = self.types[t];
        let n = volume::check_allocation(brik, self.dims, stored.bytes(), opts.max_voxel_bytes)?;
        let voxels = n as u128;
        let skip: u128 = self.types[..t].iter().map(|s| voxels * s.bytes() as u128).sum();
        let bytes = n * stored.bytes();
        let end = skip + bytes as u128;
        let meta = crate::files::check_regular_file(brik)?;
        let file = BufReader::new(File::open(brik).map_err(|e| Error::io(brik, e))?);
        let what = format!("the {}×{}×{} samples of sub-brick {t}", self.dims[0], self.dims[1], self.dims[2]);
        if self.files.gzip {
            if end > u128::from(meta.len()) * u128::from(MAX_DEFLATE_RATIO) {
                return Err(Error::truncated(
                    brik,
                    format!("{what} end at byte {end}, more than a {}-byte gzip file inflates to", meta.len()),
                ));
            }
            read_span(brik, &mut MultiGzDecoder::new(file), skip, bytes, &what, opts)
        } else {
            if end > u128::from(meta.len()) {
                return Err(Error::truncated(
                    brik,
                    format!("{what} end at byte {end} but the file has {} bytes", meta.len()),
                ));
            }
            let mut file = file;
            read_span(brik, &mut file, skip, bytes, &what, opts)
        }
    }
}

/// `bytes` bytes of `src` after `skip`, read a chunk at a time with progress.
fn read_span<S: Source>(
    path: &Path,
    src: &mut S,
    skip: u128,
    bytes: usize,
    what: &str,
    opts: &mut LoadOptions,
) -> Result<Vec<u8>> {
    let skip = u64::try_from(skip).unwrap_or(u64::MAX);
    let seeks = src.seek_forward(skip).map_err(|e| Error::io(path, e))?;
    let total = bytes as u64 + if seeks { 0 } else { skip };
    let mut done = 0u64;
    opts.report(path, "reading", done, total)?;
    let mut scratch = vec![0u8; CHUNK_BYTES.min(bytes.max(1))];
    if !seeks {
        let mut left = skip;
        while left > 0 {
            let k = usize::try_from(left).unwrap_or(usize::MAX).min(scratch.len());
            fill(path, src, &mut scratch[..k], "the sub-bricks before the one chosen")?;
            left -= k as u64;
            done += k as u64;
            opts.report(path, "reading", done, total)?;
        }
    }
    let mut out = volume::try_with_capacity(path, bytes, "the sub-brick's samples")?;
    out.resize(bytes, 0);
    for chunk in out.chunks_mut(CHUNK_BYTES) {
        fill(path, src, chunk, what)?;
        done += chunk.len() as u64;
        opts.report(path, "reading", done, total)?;
    }
    Ok(out)
}

/// Reads one sub-brick of the AFNI dataset `path` names (its `.HEAD`, `.BRIK` or `.BRIK.gz`) as a volume: the one
/// [`LoadOptions::frame`] chooses when there are several (otherwise [`ErrorKind::FrameRequired`]), scaled by its
/// factor when it has one (into the narrowest type that holds the values, as a NIfTI rescale).
///
/// # Errors
/// A file is missing, malformed, truncated, or of a type not read; each names the file.
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    let d = Dataset::open(path)?;
    let frames = d.types.len();
    let chosen = match (&d.files.selector, opts.frame) {
        (Some(s), None) => Some(sub_brick(&d.files.head, s, frames)?),
        (Some(s), Some(t)) => {
            return Err(Error::invalid(
                &d.files.head,
                format!("the name selects sub-brick [{s}] and frame {t} was asked for too: choose one way"),
            ));
        }
        (None, frame) => frame,
    };
    let t = match (chosen, frames) {
        (None, 1) => 0,
        (None, frames) => return Err(Error::new(&d.files.head, ErrorKind::FrameRequired { frames })),
        (Some(t), n) if t >= n => {
            return Err(Error::invalid(&d.files.head, format!("sub-brick {t} is out of range: the dataset has {n}")));
        }
        (Some(t), _) => t,
    };
    let (big_endian, order_warning) = d.header.big_endian()?;
    let (lps_from_index, _) = d.header.grid()?;
    let raw = d.brick_bytes(t, opts)?;
    let stored = d.types[t];
    let factor = d.header.factor(t)?;
    let data = if let Some(f) = factor {
        sample::with_stored_type!(stored, T => rescale_samples::<T>(&d.files.brik, &raw, d.dims, big_endian, (f, 0.0), opts.max_voxel_bytes)?)
    } else {
        let n = raw.len() / stored.bytes();
        let mut data = VoxelData::try_empty(&d.files.brik, stored.unscaled(), n, "the voxel samples")?;
        sample::with_stored_type!(stored, T => data.extend_from(sample::decode::<T>(&raw, big_endian)));
        data
    };
    let mut volume = Volume::new(&d.files.brik, d.dims, data, lps_from_index, GeometrySource::Afni)?;
    if let Some(slope) = factor {
        volume.rescale = Rescale { slope, intercept: 0.0, applied: true };
    }
    volume.metadata.description = d.header.labels().get(t).filter(|l| !l.is_empty()).cloned();
    volume.metadata.warnings.extend(order_warning);
    Ok(volume)
}

/// Reads the `3dQwarp` warp the AFNI dataset `path` names as a pull-back displacement field on its grid (module docs,
/// "Warps").
///
/// # Errors
/// As [`read()`]; a dataset whose first three sub-bricks are not labelled `x_delta`, `y_delta`, `z_delta`; an oblique
/// grid; a displacement that is not finite.
pub fn read_warp(path: &Path) -> Result<ReadField> {
    let d = Dataset::open(path)?;
    if let Some(s) = &d.files.selector {
        return Err(Error::unsupported(
            &d.files.head,
            format!("a warp is read whole, its x_delta, y_delta and z_delta: drop the sub-brick selector [{s}]"),
        ));
    }
    if !d.header.is_warp() {
        let labels = d.header.labels();
        return Err(Error::unsupported(
            &d.files.head,
            format!(
                "an AFNI dataset but not a 3dQwarp warp: its sub-bricks are labelled {labels:?}, where a warp's first \
                 three are {WARP_LABELS:?}"
            ),
        ));
    }
    let (lps_from_index, oblique) = d.header.grid()?;
    if oblique {
        return Err(Error::unsupported(
            &d.files.head,
            "the warp's grid is oblique (IJK_TO_DICOM_REAL is not its cardinal grid), where AFNI applies a warp on \
             the cardinal one: deoblique the base before 3dQwarp (3dWarp -deoblique)",
        ));
    }
    let (big_endian, order_warning) = d.header.big_endian()?;
    let mut opts = LoadOptions::new();
    let n = volume::check_allocation(&d.files.brik, d.dims, 12, opts.max_voxel_bytes)?;
    let mut displacements_lps = volume::try_with_capacity(&d.files.brik, n, "the warp's displacements")?;
    displacements_lps.resize(n, [0.0f32; 3]);
    for (c, label) in WARP_LABELS.iter().enumerate() {
        let raw = d.brick_bytes(c, &mut opts)?;
        let f = d.header.factor(c)?.unwrap_or(1.0);
        let stored = d.types[c];
        let values: Vec<f32> = sample::with_stored_type!(stored, T => sample::decode::<T>(&raw, big_endian).map(|x| (f * sample::Stored::to_f64(x)) as f32).collect());
        for (v, (out, x)) in displacements_lps.iter_mut().zip(values).enumerate() {
            if !x.is_finite() {
                return Err(Error::invalid(
                    &d.files.brik,
                    format!("{label} is {x} at voxel {v} (i fastest): a warp's displacements are finite"),
                ));
            }
            out[c] = x;
        }
    }
    let field =
        DisplacementField { dims: d.dims, lps_from_index, geometry_source: GeometrySource::Afni, displacements_lps };
    Ok(ReadField {
        field,
        source: FieldSource::Field(FieldFormat::Afni),
        direction: Some(FieldDirection::Pullback),
        warnings: order_warning.into_iter().collect(),
    })
}
