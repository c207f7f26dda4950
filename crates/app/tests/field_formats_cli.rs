//! `warpbench field --format itk|ants|nrrd|metaimage --direction pullback|forward` end to end, each flavour read by a reader
//! written here from its published layout (not warpbench_io's), and compared with what its own tool read:
//!
//! - `tests/data/itk/field_formats_reference.json` (made by `data-scripts/field_formats_ref.py`, provenance in that
//!   folder's README) holds SimpleITK 2.5.7's and nibabel's vectors (LPS mm) at 80 voxels of each flavour written
//!   from the MRI fixture and `field_pairs.csv`; the script checked them against warpbench's exact maps;
//! - here the files are written again and read by hand: the NIfTI-1 header (`dim`, `intent_code`, `datatype`,
//!   `vox_offset`, `srow_*`) and its component planes, RAS (intent 1006, ITK's DISPVECT) or LPS (intent 1007, the 5-D
//!   warp file ANTs documents); the NRRD header (`kinds`, `space`, `space directions`, `displacement field type`) and
//!   its interleaved gzip samples; the MetaImage header (`TransformMatrix`, `ElementSpacing`, `Offset`,
//!   `ElementNumberOfChannels`) and its interleaved samples, zlib after the header (`.mha`) or raw beside it (`.mhd`).
//!   Every reading must equal the recorded one;
//! - each flavour, interpolated trilinearly here from the hand-read vectors, moves 12 off-grid points where ITK's
//!   `DisplacementFieldTransform` (the class ANTs and Slicer apply fields with) moved them, to 1e-4 mm;
//! - the forward field obeys its law: a moving point y goes to y + D(y), which `points --from fixed` brings back to y
//!   within the warp's inverse consistency;
//! - on a pair whose grids differ (a small flipped moving volume), the forward field lies on the moving grid (or
//!   `--reference`'s) and holds the solver's d(y) − y at every voxel; the `--json` summary names its grid, format and
//!   direction; and the defaults are `--format itk --direction pullback` on the fixed grid, byte for byte.

mod common;

use std::io::Read;
use std::path::{Path, PathBuf};

use common::{assert_ok, data, mri, utf8, warpbench};
use serde_json::Value;
use warpbench_app::fit;
use warpbench_app::inputs::volume_box;
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving, as_fixed, as_moving};
use warpbench_solver::warp::Warp;

/// Both readings are of the same float32 numbers.
const TOLERANCE_MM: f64 = 1e-6;

fn reference() -> Value {
    let text = std::fs::read_to_string(data("itk/field_formats_reference.json")).expect("read the reference");
    serde_json::from_str(&text).expect("JSON")
}

fn vectors(v: &Value) -> Vec<[f64; 3]> {
    v.as_array().expect("a list").iter().map(|p| std::array::from_fn(|k| p[k].as_f64().expect("a number"))).collect()
}

fn gunzip(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(bytes).read_to_end(&mut out).expect("gzip");
    out
}

/// What the test reads from a NIfTI-1 vector field (little-endian, as warpbench writes).
struct Nifti {
    dim: [i16; 8],
    intent_code: i16,
    datatype: i16,
    sform_code: i16,
    /// srow_x, srow_y, srow_z: RAS mm from the voxel index.
    srow: [[f32; 4]; 3],
    /// Component planes: [c][voxel], voxel = i + X (j + Y k).
    planes: [Vec<f32>; 3],
}

fn read_nifti(path: &Path) -> Nifti {
    let raw = std::fs::read(path).expect("read");
    let bytes = if raw.starts_with(&[0x1f, 0x8b]) { gunzip(&raw) } else { raw };
    let i16_at = |o: usize| i16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let f32_at = |o: usize| f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    assert_eq!(i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]), 348, "sizeof_hdr");
    assert_eq!(&bytes[344..348], b"n+1\0", "a single-file NIfTI-1");
    let dim: [i16; 8] = std::array::from_fn(|k| i16_at(40 + 2 * k));
    let vox_offset = f32_at(108) as usize;
    let voxels = (dim[1] as usize) * (dim[2] as usize) * (dim[3] as usize);
    let planes = std::array::from_fn(|c| (0..voxels).map(|n| f32_at(vox_offset + 4 * (c * voxels + n))).collect());
    Nifti {
        dim,
        intent_code: i16_at(68),
        datatype: i16_at(70),
        sform_code: i16_at(254),
        srow: std::array::from_fn(|r| std::array::from_fn(|c| f32_at(280 + 16 * r + 4 * c))),
        planes,
    }
}

/// What the test reads from a NRRD vector field: the header's fields and key/value pairs, and the samples.
struct Nrrd {
    fields: Vec<(String, String)>,
    samples: Vec<f32>,
}

impl Nrrd {
    fn field(&self, key: &str) -> &str {
        self.fields.iter().find(|(k, _)| k == key).map_or_else(|| panic!("no {key:?} in the header"), |(_, v)| v)
    }
}

fn read_nrrd(path: &Path) -> Nrrd {
    let bytes = std::fs::read(path).expect("read");
    let end = bytes.windows(2).position(|w| w == b"\n\n").expect("a blank line ends the header");
    let header = std::str::from_utf8(&bytes[..end]).expect("text");
    assert!(header.starts_with("NRRD000"), "{header}");
    let fields = header
        .lines()
        .skip(1)
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let (k, v) = l.split_once(":=").or_else(|| l.split_once(": ")).expect("key: value");
            (k.to_string(), v.trim().to_string())
        })
        .collect();
    let nrrd = Nrrd { fields, samples: Vec::new() };
    assert_eq!(nrrd.field("encoding"), "gzip");
    assert_eq!(nrrd.field("endian"), "little");
    let body = gunzip(&bytes[end + 2..]);
    let samples = body.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Nrrd { samples, ..nrrd }
}

/// What the test reads from a MetaImage vector field: the header's `Key = Value` fields in order, and the samples
/// (after the header in a `.mha`, zlib-compressed when it says so; else in the data file it names).
struct MetaImage {
    fields: Vec<(String, String)>,
    samples: Vec<f32>,
}

impl MetaImage {
    fn field(&self, key: &str) -> &str {
        self.fields.iter().find(|(k, _)| k == key).map_or_else(|| panic!("no {key:?} in the header"), |(_, v)| v)
    }

    fn numbers(&self, key: &str) -> Vec<f64> {
        self.field(key).split_whitespace().map(|t| t.parse().expect("a number")).collect()
    }
}

fn read_metaimage(path: &Path) -> MetaImage {
    let bytes = std::fs::read(path).expect("read");
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.last().is_none_or(|(k, _): &(String, String)| k != "ElementDataFile") {
        let end = at + bytes[at..].iter().position(|&b| b == b'\n').expect("a header line");
        let line = std::str::from_utf8(&bytes[at..end]).expect("text");
        let (k, v) = line.split_once(" = ").expect("Key = Value");
        fields.push((k.to_string(), v.to_string()));
        at = end + 1;
    }
    let image = MetaImage { fields, samples: Vec::new() };
    let data = match image.field("ElementDataFile") {
        "LOCAL" => bytes[at..].to_vec(),
        name => std::fs::read(path.with_file_name(name)).expect("the data file"),
    };
    let data = if image.field("CompressedData") == "True" {
        assert_eq!(image.field("CompressedDataSize"), data.len().to_string());
        let mut out = Vec::new();
        flate2::read::ZlibDecoder::new(data.as_slice()).read_to_end(&mut out).expect("zlib");
        out
    } else {
        data
    };
    let samples = data.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    MetaImage { samples, ..image }
}

/// `warpbench field` on the MRI fixture and the field pairs with `flags`, into `out`.
fn write(out: &Path, flags: &[&str]) {
    let (f, l) = (mri(), data("itk/field_pairs.csv"));
    let mut args = vec!["field", "--fixed", utf8(&f), "--moving", utf8(&f), "--landmarks", utf8(&l)];
    args.extend_from_slice(flags);
    args.extend(["--out", utf8(out), "--quiet"]);
    assert_ok(&warpbench(&args));
}

fn indices(reference: &Value) -> Vec<[usize; 3]> {
    reference["indices"]
        .as_array()
        .expect("indices")
        .iter()
        .map(|v| std::array::from_fn(|k| v[k].as_u64().expect("an index") as usize))
        .collect()
}

fn flavour<'a>(reference: &'a Value, name: &str) -> &'a Value {
    reference["flavours"].as_array().expect("flavours").iter().find(|f| f["name"] == name).expect("the flavour")
}

fn assert_close(got: &[[f64; 3]], want: &[[f64; 3]], what: &str) {
    assert_eq!(got.len(), want.len());
    for (n, (g, w)) in got.iter().zip(want).enumerate() {
        let err = (0..3).map(|k| (g[k] - w[k]).abs()).fold(0.0, f64::max);
        assert!(err <= TOLERANCE_MM, "{what}: voxel {}: {g:?} vs {w:?}", n + 1);
    }
}

/// The MRI fixture's dims (91 × 109 × 91).
const DIMS: [usize; 3] = [91, 109, 91];

fn voxel(ijk: [usize; 3]) -> usize {
    ijk[0] + DIMS[0] * (ijk[1] + DIMS[1] * ijk[2])
}

#[test]
fn the_nifti_flavours_read_by_hand_equal_simpleitk_and_nibabel() {
    let reference = reference();
    let idx = indices(&reference);
    let dir = tempfile::tempdir().expect("tempdir");
    let volume = warpbench_io::open(mri()).expect("the fixture");
    let m = volume.lps_from_index.rows();
    for (name, flags, intent, ras) in
        [("itk", ["--format", "itk"], 1006, true), ("ants", ["--format", "ants"], 1007, false)]
    {
        let path = dir.path().join(format!("{name}.nii.gz"));
        write(&path, &flags);
        let n = read_nifti(&path);
        assert_eq!(n.dim, [5, 91, 109, 91, 1, 3, 1, 1], "{name}: vectors in the 5th dimension");
        assert_eq!(n.intent_code, intent, "{name}");
        assert_eq!(n.datatype, 16, "{name}: float32");
        assert!(n.sform_code > 0, "{name}: the sform holds the geometry");
        // The sform is RAS: the LPS matrix with its first two rows negated.
        for (r, (srow, lps_row)) in n.srow.iter().zip(&m).enumerate() {
            let sign = if r < 2 { -1.0 } else { 1.0 };
            for (c, (&got, &lps)) in srow.iter().zip(lps_row).enumerate() {
                assert!((f64::from(got) - sign * lps).abs() < 1e-4, "{name}: srow[{r}][{c}]");
            }
        }
        let lps: Vec<[f64; 3]> = idx
            .iter()
            .map(|&ijk| {
                let v = n.planes.each_ref().map(|p| f64::from(p[voxel(ijk)]));
                if ras { [-v[0], -v[1], v[2]] } else { v }
            })
            .collect();
        let f = flavour(&reference, name);
        assert_eq!(f["nibabel"]["intent_code"], intent);
        assert_close(&lps, &vectors(&f["sitk_vectors_lps"]), &format!("{name} vs SimpleITK"));
        assert_close(&lps, &vectors(&f["nibabel_vectors_lps"]), &format!("{name} vs nibabel"));
        assert!(lps.iter().flatten().any(|v| v.abs() > 1.0), "{name}: the field is not zero");
    }
}

#[test]
fn the_nrrd_flavour_read_by_hand_equals_simpleitk_and_states_its_direction() {
    let reference = reference();
    let idx = indices(&reference);
    let dir = tempfile::tempdir().expect("tempdir");
    let volume = warpbench_io::open(mri()).expect("the fixture");
    let path = dir.path().join("field.nrrd");
    write(&path, &["--format", "nrrd"]);
    let nrrd = read_nrrd(&path);
    assert_eq!(nrrd.field("type"), "float");
    assert_eq!(nrrd.field("dimension"), "4");
    assert_eq!(nrrd.field("sizes"), "3 91 109 91");
    assert_eq!(nrrd.field("kinds"), "vector domain domain domain");
    assert_eq!(nrrd.field("space"), "left-posterior-superior");
    assert_eq!(nrrd.field("displacement field type"), "resampling");
    // space directions: none, then the columns of the LPS matrix; origin its translation.
    let m = volume.lps_from_index.rows();
    let numbers = |s: &str| -> Vec<f64> {
        s.split(|c: char| "(), ".contains(c))
            .filter(|t| !t.is_empty() && *t != "none")
            .map(|t| t.parse().expect("num"))
            .collect()
    };
    let directions = numbers(nrrd.field("space directions"));
    assert!(nrrd.field("space directions").starts_with("none"));
    for c in 0..3 {
        for r in 0..3 {
            assert!((directions[3 * c + r] - m[r][c]).abs() < 1e-9, "space directions column {c}");
        }
    }
    let origin = numbers(nrrd.field("space origin"));
    for r in 0..3 {
        assert!((origin[r] - m[r][3]).abs() < 1e-9, "space origin");
    }
    assert_eq!(nrrd.samples.len(), 3 * 91 * 109 * 91);
    let lps: Vec<[f64; 3]> =
        idx.iter().map(|&ijk| std::array::from_fn(|c| f64::from(nrrd.samples[3 * voxel(ijk) + c]))).collect();
    assert_close(&lps, &vectors(&flavour(&reference, "nrrd")["sitk_vectors_lps"]), "nrrd vs SimpleITK");

    // The forward field says so.
    let forward = dir.path().join("forward.nrrd");
    write(&forward, &["--format", "nrrd", "--direction", "forward"]);
    assert_eq!(read_nrrd(&forward).field("displacement field type"), "modeling");
}

#[test]
fn the_metaimage_flavour_read_by_hand_equals_simpleitk() {
    let reference = reference();
    let idx = indices(&reference);
    let dir = tempfile::tempdir().expect("tempdir");
    let volume = warpbench_io::open(mri()).expect("the fixture");
    let m = volume.lps_from_index.rows();
    for (name, compressed, data_file) in [("field.mha", "True", "LOCAL"), ("field.mhd", "False", "field.raw")] {
        let path = dir.path().join(name);
        write(&path, &["--format", "metaimage"]);
        let image = read_metaimage(&path);
        for (key, want) in [
            ("ObjectType", "Image"),
            ("NDims", "3"),
            ("BinaryData", "True"),
            ("BinaryDataByteOrderMSB", "False"),
            ("CompressedData", compressed),
            ("DimSize", "91 109 91"),
            ("ElementNumberOfChannels", "3"),
            ("ElementType", "MET_FLOAT"),
            ("ElementDataFile", data_file),
        ] {
            assert_eq!(image.field(key), want, "{name}: {key}");
        }
        // lps_from_index = [D · diag(spacing) | offset], D's columns in TransformMatrix one after another.
        let (d, spacing, offset) =
            (image.numbers("TransformMatrix"), image.numbers("ElementSpacing"), image.numbers("Offset"));
        for r in 0..3 {
            for c in 0..3 {
                assert!((d[3 * c + r] * spacing[c] - m[r][c]).abs() < 1e-9, "{name}: column {c}");
            }
            assert!((offset[r] - m[r][3]).abs() < 1e-9, "{name}: offset");
        }
        assert_eq!(image.samples.len(), 3 * 91 * 109 * 91, "{name}: three interleaved components a voxel");
        let lps: Vec<[f64; 3]> =
            idx.iter().map(|&ijk| std::array::from_fn(|c| f64::from(image.samples[3 * voxel(ijk) + c]))).collect();
        assert_close(&lps, &vectors(&flavour(&reference, "metaimage")["sitk_vectors_lps"]), name);
    }
}

#[test]
fn a_moving_point_moved_by_the_forward_field_comes_back_by_the_pullback() {
    let reference = reference();
    let idx = indices(&reference);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("forward.nii.gz");
    write(&path, &["--format", "itk", "--direction", "forward"]);
    let n = read_nifti(&path);
    let forward: Vec<[f64; 3]> = idx
        .iter()
        .map(|&ijk| {
            let v = n.planes.each_ref().map(|p| f64::from(p[voxel(ijk)]));
            [-v[0], -v[1], v[2]]
        })
        .collect();
    assert_close(&forward, &vectors(&flavour(&reference, "itk_forward")["sitk_vectors_lps"]), "forward vs SimpleITK");

    // y + D(y), then u: back at y within the inverse consistency of this mild TPS (measured: well under 0.1 mm).
    let volume = warpbench_io::open(mri()).expect("the fixture");
    let ys: Vec<[f64; 3]> = idx
        .iter()
        .map(|&ijk| {
            volume
                .lps_from_index
                .apply_point(warpbench_io::geometry::Point3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64))
                .coords()
        })
        .collect();
    let moved: PathBuf = dir.path().join("moved.csv");
    let lines: Vec<String> =
        ys.iter().zip(&forward).map(|(y, d)| format!("{},{},{}", y[0] + d[0], y[1] + d[1], y[2] + d[2])).collect();
    std::fs::write(&moved, lines.join("\n") + "\n").expect("write");
    let back = dir.path().join("back.csv");
    let (f, l) = (mri(), data("itk/field_pairs.csv"));
    let args = ["points", "--fixed", utf8(&f), "--moving", utf8(&f), "--landmarks", utf8(&l), "--from", "fixed"];
    let mut args = args.to_vec();
    args.extend(["--in", utf8(&moved), "--out", utf8(&back), "--quiet"]);
    assert_ok(&warpbench(&args));
    // What the solver says u(d(y)) is, fitted as the commands fit (TPS over the volume's box, both ways).
    let pairs = warpbench_io::landmarks::read_bigwarp_csv(&l).expect("pairs");
    let fixed: Vec<_> = pairs.iter().map(|p| as_fixed(p.fixed.expect("fixed"))).collect();
    let moving: Vec<_> = pairs.iter().map(|p| as_moving(p.moving.expect("moving"))).collect();
    let method = Method::Tps { stiffness: 0.0 };
    let d = fit::forward(&method, &fixed, &moving, volume_box::<Moving>(&volume)).expect("d");
    let u = fit::pullback(&method, &fixed, &moving, volume_box::<Fixed>(&volume)).expect("u");
    let text = std::fs::read_to_string(&back).expect("read");
    let (mut worst, mut consistency, mut moved_most) = (0.0f64, 0.0f64, 0.0f64);
    for ((line, y), dy) in text.lines().zip(&ys).zip(&forward) {
        let p: Vec<f64> = line.split(',').map(|v| v.parse().expect("a number")).collect();
        let want = u.apply_raw(d.apply_raw(*y));
        worst = worst.max((0..3).map(|k| (p[k] - want[k]).powi(2)).sum::<f64>().sqrt());
        consistency = consistency.max((0..3).map(|k| (want[k] - y[k]).powi(2)).sum::<f64>().sqrt());
        moved_most = moved_most.max(dy.iter().map(|v| v * v).sum::<f64>().sqrt());
    }
    assert!(moved_most > 3.0, "the forward field moves points ({moved_most} mm)");
    // The field is float32: D(y) is rounded by < 1e-6 mm, and u does not stretch that much.
    assert!(worst < 1e-5, "u(y + D(y)) is {worst} mm from the solver's u(d(y)) (inverse consistency {consistency} mm)");
    assert!(consistency < 0.5, "a mild TPS is nearly inverse-consistent: {consistency} mm");
}

/// The field's LPS vector at voxel `ijk`, however the flavour stores it.
type VectorAt<'a> = Box<dyn Fn([usize; 3]) -> [f64; 3] + 'a>;

/// Trilinear interpolation of `at` at the continuous index `c` (inside the grid), as ITK's
/// `VectorLinearInterpolateImageFunction` does it.
fn trilinear(at: &VectorAt, c: [f64; 3]) -> [f64; 3] {
    let base: [usize; 3] = std::array::from_fn(|k| c[k].floor() as usize);
    let t: [f64; 3] = std::array::from_fn(|k| c[k] - base[k] as f64);
    let mut sum = [0.0; 3];
    for corner in 0..8 {
        let step: [usize; 3] = std::array::from_fn(|k| (corner >> k) & 1);
        let weight: f64 = (0..3).map(|k| if step[k] == 1 { t[k] } else { 1.0 - t[k] }).product();
        let v = at(std::array::from_fn(|k| base[k] + step[k]));
        for k in 0..3 {
            sum[k] += weight * v[k];
        }
    }
    sum
}

#[test]
fn every_flavour_read_by_hand_moves_off_grid_points_as_itks_displacement_field_transform() {
    let reference = reference();
    let continuous: Vec<[f64; 3]> = vectors(&reference["off_grid_indices"]);
    let points_lps = vectors(&reference["off_grid_points_lps"]);
    let dir = tempfile::tempdir().expect("tempdir");
    // ITK placed the off-grid indices where warpbench's reading of the volume does.
    let volume = warpbench_io::open(mri()).expect("the fixture");
    let placed: Vec<[f64; 3]> = continuous
        .iter()
        .map(|c| volume.lps_from_index.apply_point(warpbench_io::geometry::Point3::new(c[0], c[1], c[2])).coords())
        .collect();
    assert_close(&placed, &points_lps, "off-grid points: ITK's index to physical vs warpbench's lps_from_index");
    for (name, flags) in [
        ("itk", ["--format", "itk", "--direction", "pullback"]),
        ("ants", ["--format", "ants", "--direction", "pullback"]),
        ("nrrd", ["--format", "nrrd", "--direction", "pullback"]),
        ("itk_forward", ["--format", "itk", "--direction", "forward"]),
        ("metaimage", ["--format", "metaimage", "--direction", "pullback"]),
    ] {
        let extension = match name {
            "nrrd" => "nrrd",
            "metaimage" => "mha",
            _ => "nii.gz",
        };
        let path = dir.path().join(format!("{name}.{extension}"));
        write(&path, &flags);
        let at: VectorAt = if name == "nrrd" || name == "metaimage" {
            let samples = if name == "nrrd" { read_nrrd(&path).samples } else { read_metaimage(&path).samples };
            Box::new(move |ijk| std::array::from_fn(|c| f64::from(samples[3 * voxel(ijk) + c])))
        } else {
            let n = read_nifti(&path);
            let ras = n.intent_code == 1006;
            Box::new(move |ijk| {
                let v = n.planes.each_ref().map(|p| f64::from(p[voxel(ijk)]));
                if ras { [-v[0], -v[1], v[2]] } else { v }
            })
        };
        let moved: Vec<[f64; 3]> = continuous
            .iter()
            .zip(&points_lps)
            .map(|(&c, p)| {
                let d = trilinear(&at, c);
                std::array::from_fn(|k| p[k] + d[k])
            })
            .collect();
        let itk = vectors(&flavour(&reference, name)["sitk_transform_point_lps"]);
        // ITK interpolates in float64 from the same float32 vectors: the sums agree to rounding; 1e-4 mm is the
        // issue's bar.
        for (n, (got, want)) in moved.iter().zip(&itk).enumerate() {
            let err = (0..3).map(|k| (got[k] - want[k]).abs()).fold(0.0, f64::max);
            assert!(err <= 1e-4, "{name}: off-grid point {}: {got:?} vs ITK's {want:?}", n + 1);
        }
        let moved_most =
            moved.iter().zip(&points_lps).map(|(m, p)| (0..3).map(|k| (m[k] - p[k]).abs()).fold(0.0, f64::max));
        assert!(moved_most.fold(0.0, f64::max) > 1.0, "{name}: the points move");
    }
}

/// A small moving volume on its own grid (20×18×16, 2.5 × 2 × 3 mm, j flipped), six pairs inside it and inside the
/// MRI (the fixed volume), in `dir`: (moving volume, landmark CSV).
fn small_moving_pair(dir: &Path) -> (PathBuf, PathBuf) {
    let moving = dir.join("small_moving.nii.gz");
    let dims = [20, 18, 16];
    let lps_from_index =
        warpbench_io::geometry::Transform::from_scale_translation([2.5, -2.0, 3.0], [-24.0, 17.0, -22.0]);
    let samples = (0..dims.iter().product::<usize>()).map(|n| (n % 97) as f32).collect();
    let volume = warpbench_io::Volume::new(
        &moving,
        dims,
        warpbench_io::VoxelData::F32(samples),
        lps_from_index,
        warpbench_io::GeometrySource::NiftiSform { code: 1 },
    )
    .expect("volume");
    warpbench_io::nifti::write(&moving, &volume).expect("write the moving volume");
    let fixed_points: [[f64; 3]; 6] = [
        [-12.0, 10.0, 8.0],
        [12.0, 10.0, -8.0],
        [-12.0, -10.0, -8.0],
        [12.0, -10.0, 8.0],
        [0.0, 0.0, 14.0],
        [0.0, 0.0, 0.0],
    ];
    let local =
        [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-1.5, 0.0, 1.0], [0.0, 0.0, -2.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]];
    let pairs: Vec<([f64; 3], [f64; 3])> = fixed_points
        .iter()
        .zip(local)
        .map(|(q, l)| ([q[0] + 2.0 + l[0], q[1] - 1.0 + l[1], q[2] + 1.5 + l[2]], *q))
        .collect();
    let landmarks = dir.join("small_pairs.csv");
    common::write_pairs_csv(&landmarks, &pairs);
    (moving, landmarks)
}

/// `warpbench field` on the MRI (fixed) and the small moving volume with `flags`, `--json`: the summary.
fn write_small(moving: &Path, landmarks: &Path, out: &Path, flags: &[&str]) -> Value {
    let f = mri();
    let mut args = vec!["field", "--fixed", utf8(&f), "--moving", utf8(moving), "--landmarks", utf8(landmarks)];
    args.extend_from_slice(flags);
    args.extend(["--json", "--quiet", "--out", utf8(out)]);
    let run = warpbench(&args);
    assert_ok(&run);
    serde_json::from_slice(&run.stdout).expect("the JSON summary")
}

#[test]
fn the_forward_field_lies_on_the_moving_grid_and_holds_d_of_y_minus_y() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (moving_path, landmarks) = small_moving_pair(dir.path());
    let out = dir.path().join("forward_ants.nii.gz");
    let json = write_small(&moving_path, &landmarks, &out, &["--format", "ants", "--direction", "forward"]);
    let moving = warpbench_io::open(&moving_path).expect("the moving volume");
    assert_eq!(
        (json["schema"].as_str(), json["grid"].as_str(), json["format"].as_str(), json["direction"].as_str()),
        (Some("warpbench-field/1"), Some("moving"), Some("ants"), Some("forward"))
    );
    assert_eq!(json["dims"], serde_json::json!([20, 18, 16]));
    assert_eq!(json["lps_from_index"], serde_json::json!(moving.lps_from_index.rows()));

    // Read by hand: the moving grid, in ANTs' layout, and at every voxel centre y the vector d(y) − y.
    let n = read_nifti(&out);
    assert_eq!(n.dim, [5, 20, 18, 16, 1, 3, 1, 1]);
    assert_eq!(n.intent_code, 1007);
    let pairs = warpbench_io::landmarks::read_bigwarp_csv(&landmarks).expect("pairs");
    let fixed_points: Vec<_> = pairs.iter().map(|p| as_fixed(p.fixed.expect("fixed"))).collect();
    let moving_points: Vec<_> = pairs.iter().map(|p| as_moving(p.moving.expect("moving"))).collect();
    let d = fit::forward(&Method::Tps { stiffness: 0.0 }, &fixed_points, &moving_points, volume_box::<Moving>(&moving))
        .expect("d");
    let (mut worst, mut largest) = (0.0f64, 0.0f64);
    for k in 0..16 {
        for j in 0..18 {
            for i in 0..20 {
                let y = moving
                    .lps_from_index
                    .apply_point(warpbench_io::geometry::Point3::new(i as f64, j as f64, k as f64))
                    .coords();
                let dy = d.apply_raw(y);
                let voxel = i + 20 * (j + 18 * k);
                for c in 0..3 {
                    let want = dy[c] - y[c];
                    worst = worst.max((f64::from(n.planes[c][voxel]) - want).abs());
                    largest = largest.max(want.abs());
                }
            }
        }
    }
    // float32 of a few mm: rounding under 1e-6 mm.
    assert!(worst < 1e-5, "the forward field is {worst} mm from d(y) − y");
    assert!(largest > 1.0, "the field moves points ({largest} mm)");

    // --reference sets the forward field's grid too.
    let on_mri = dir.path().join("forward_on_mri.nrrd");
    let mri_path = mri();
    let json = write_small(
        &moving_path,
        &landmarks,
        &on_mri,
        &["--format", "nrrd", "--direction", "forward", "--reference", utf8(&mri_path)],
    );
    assert_eq!((json["grid"].as_str(), &json["dims"]), (Some("reference"), &serde_json::json!(DIMS)));
    assert_eq!(read_nrrd(&on_mri).field("displacement field type"), "modeling");
}

#[test]
fn the_defaults_are_the_itk_flavour_and_the_pullback_on_the_fixed_grid() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (moving, landmarks) = small_moving_pair(dir.path());
    // The small volume as the grid keeps the files small; the fit is the same (over the fixed box).
    let (default, explicit) = (dir.path().join("default.nii.gz"), dir.path().join("explicit.nii.gz"));
    let reference = ["--reference", utf8(&moving)];
    let json = write_small(&moving, &landmarks, &default, &reference);
    let mut flags = reference.to_vec();
    flags.extend(["--format", "itk", "--direction", "pullback"]);
    let explicit_json = write_small(&moving, &landmarks, &explicit, &flags);
    assert_eq!((json["format"].as_str(), json["direction"].as_str()), (Some("itk"), Some("pullback")));
    assert_eq!(json["max_displacement_mm"], explicit_json["max_displacement_mm"]);
    let bytes = std::fs::read(&default).expect("read");
    assert!(bytes == std::fs::read(&explicit).expect("read"), "the default is --format itk --direction pullback");
    assert_eq!(read_nifti(&default).intent_code, 1006);
    // Without --reference the pull-back lies on the fixed grid.
    let json = write_small(&moving, &landmarks, &dir.path().join("on_fixed.nii.gz"), &[]);
    assert_eq!((json["grid"].as_str(), &json["dims"]), (Some("fixed"), &serde_json::json!(DIMS)));
}

#[test]
fn an_ome_zarr_field_holds_the_itk_flavours_vectors_and_warps_alike() {
    // `field --out x.ome.zarr` (the name picks the ngff flavour) on the MRI grid (stored RAS, written in LPS order):
    // each voxel's vector is where the itk flavour has it, equal to the float32 bit; `warp --field` through either
    // writes the same volume; `--direction forward` writes the forward map on the moving grid as well.
    let dir = tempfile::tempdir().expect("tempdir");
    let (zarr, nifti) = (dir.path().join("u.ome.zarr"), dir.path().join("u.nii.gz"));
    write(&zarr, &[]);
    write(&nifti, &[]);
    let read = |p: &Path| warpbench_io::displacement::read_field_info(p).expect("read back");
    let (z, n) = (read(&zarr), read(&nifti));
    assert_eq!(z.source.name(), "ngff");
    assert!(z.warnings.is_empty(), "{:?}", z.warnings);
    let (z, n) = (z.field, n.field);
    let index_from_lps = z.lps_from_index.inverse().expect("invertible");
    for k in 0..DIMS[2] {
        for j in 0..DIMS[1] {
            for i in 0..DIMS[0] {
                let c = n.lps_from_index.apply_point(warpbench_io::geometry::Point3::new(i as f64, j as f64, k as f64));
                let at = index_from_lps.apply_point(c).coords().map(|v| v.round() as usize);
                let got = z.displacements_lps[at[0] + z.dims[0] * (at[1] + z.dims[1] * at[2])];
                let want = n.displacements_lps[voxel([i, j, k])];
                assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "voxel ({i}, {j}, {k})");
            }
        }
    }
    let warp = |field: &Path, out: &Path| {
        let f = mri();
        assert_ok(&warpbench(&[
            "warp",
            "--fixed",
            utf8(&f),
            "--moving",
            utf8(&f),
            "--field",
            utf8(field),
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            utf8(out),
        ]));
        std::fs::read(out).expect("the warped volume")
    };
    assert_eq!(warp(&zarr, &dir.path().join("a.nii")), warp(&nifti, &dir.path().join("b.nii")));
    let forward = dir.path().join("d.ome.zarr");
    write(&forward, &["--format", "ngff", "--direction", "forward"]);
    assert_eq!(read(&forward).field.dims, z.dims);
}
