//! OME-Zarr images against ngff-zarr 0.50 (its conversion to an ITK image, the reference implementation of RFC-4's
//! anatomical orientation) and zarr-python 3.1: the fixtures of `tests/data/ngff/` (`data-scripts/ngff_fixtures.py`:
//! versions 0.4, 0.5 and 0.6; zstd, Blosc, gzip, sharded and uncompressed chunks; big-endian samples; micrometres;
//! frames; a channel axis; axes stored x slowest; a missing chunk) read to the grid and the values the reference
//! gives, and the bad ones are refused naming the folder and the problem.

use std::path::{Path, PathBuf};

use serde_json::Value;
use sha2::{Digest, Sha256};
use warpbench_io::{ErrorKind, Format, GeometrySource, LoadOptions, ngff};

use crate::support::{numbers, samples_f64};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/ngff")
}

fn reference() -> Vec<Value> {
    let path = data_dir().join("reference.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Value = serde_json::from_str(&text).expect("JSON");
    v["files"].as_array().expect("files").clone()
}

fn matrix(v: &Value) -> Vec<Vec<f64>> {
    v.as_array().expect("rows").iter().map(numbers).collect()
}

fn copy_folder(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read_dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("type").is_dir() {
            copy_folder(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).expect("copy");
        }
    }
}

/// The LPS centres of the grid's 8 corner voxels, `lps_from_index` given as a function of (i, j, k).
fn corners(dims: [usize; 3], lps_from_index: impl Fn([f64; 3]) -> [f64; 3]) -> Vec<[f64; 3]> {
    let mut out: Vec<[f64; 3]> = (0..8)
        .map(|c| lps_from_index(std::array::from_fn(|a| if c >> a & 1 == 1 { (dims[a] - 1) as f64 } else { 0.0 })))
        .collect();
    out.sort_by(|p, q| p.partial_cmp(q).expect("finite"));
    out
}

/// The reference builds the same doubles (scale × mm per unit, translation × mm per unit) in another order.
const REL_TOL: f64 = 1e-12;

#[test]
fn every_fixture_reads_to_the_reference_grid_and_values() {
    let files = reference();
    let valid: Vec<&Value> = files.iter().filter(|f| f["refuse"].is_null()).collect();
    assert_eq!(valid.len(), 10, "the reference's readable fixtures");
    for f in valid {
        let name = f["name"].as_str().expect("name");
        let path = data_dir().join(format!("{name}.ome.zarr"));
        assert_eq!(Format::detect(&path).expect("detect"), Format::OmeZarr, "{name}");
        let frames = f["frames"].as_u64().map_or(1, |n| n as usize);
        let values = f["values"].as_array().expect("values");
        assert_eq!(values.len(), frames, "{name}");
        if frames > 1 {
            let e = warpbench_io::open(&path).expect_err("a frame must be chosen");
            assert!(matches!(e.kind, ErrorKind::FrameRequired { frames: 3 }), "{name}: {e}");
        }
        for (frame, want) in values.iter().enumerate() {
            let mut opts = LoadOptions::new();
            if frames > 1 {
                opts = opts.frame(frame);
            }
            let v = opts.open(&path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(v.geometry_source, GeometrySource::OmeZarr, "{name}");
            // i is the array's last (fastest) space axis, k its first.
            let shape: Vec<usize> = numbers(&f["shape"]).into_iter().map(|x| x as usize).collect();
            let space: Vec<usize> = f["array_axes"]
                .as_array()
                .expect("axes")
                .iter()
                .zip(&shape)
                .filter(|(a, _)| a["type"] == "space")
                .map(|(_, &n)| n)
                .collect();
            assert_eq!(v.dims, [space[2], space[1], space[0]], "{name}");
            // The grid: ngff-zarr's placement (voxel 0 at the x, y, z translations; orientations as directions),
            // in mm.
            let want_m = matrix(&f["spec"]["lps_from_index_mm_ngff_zarr"]);
            let got = v.lps_from_index.rows();
            let scale = want_m.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs()));
            for r in 0..3 {
                for c in 0..4 {
                    assert!(
                        (got[r][c] - want_m[r][c]).abs() <= REL_TOL * scale,
                        "{name} [{r}][{c}]: {got:?} vs {want_m:?}"
                    );
                }
            }
            // The values: what zarr-python reads, as f32, i fastest (and as f64 where the type holds them).
            let ours = samples_f64(&v.data);
            let mut h32 = Sha256::new();
            let mut h64 = Sha256::new();
            for x in &ours {
                h32.update((*x as f32).to_le_bytes());
                h64.update(x.to_le_bytes());
            }
            assert_eq!(
                format!("{:x}", h32.finalize()),
                want["sha256_f32"].as_str().expect("sha"),
                "{name} frame {frame}"
            );
            if matches!(f["dtype"].as_str(), Some("uint8" | "int8" | "int16" | "uint16" | "float32" | "int32")) {
                assert_eq!(
                    format!("{:x}", h64.finalize()),
                    want["sha256"].as_str().expect("sha"),
                    "{name} frame {frame}"
                );
            }
            let sum: f64 = ours.iter().sum();
            let want_sum = want["sum"].as_f64().expect("sum");
            let tol = ours.iter().fold(1.0f64, |m, x| m.max(x.abs())) * ours.len() as f64 * f64::from(f32::EPSILON);
            assert!((sum - want_sum).abs() <= tol, "{name} frame {frame}: sum {sum} vs {want_sum}");
        }
    }
}

#[test]
fn the_grid_covers_the_voxel_centres_of_ngff_zarrs_itk_image() {
    // ngff-zarr's ITK image (its numbers in the file's unit; x, y, z as ITK's i, j, k) has the same voxel centres
    // as ours once the unit is mm. Two fixtures are left out, each for what ngff-zarr 0.50 does not read as the
    // specification says: the multiscale-level scale of v04_um_bigendian_i32 (not applied), and the (x, y, z)
    // storage order of v05_xyz_order_fill (its values are not ITK's).
    let mut compared = 0;
    for f in reference() {
        let name = f["name"].as_str().expect("name");
        if !f["refuse"].is_null() || f["itk"].is_null() || f["itk_values_agree"] != true {
            continue;
        }
        if name == "v04_um_bigendian_i32" {
            continue;
        }
        let v = LoadOptions::new().frame(0).open(data_dir().join(format!("{name}.ome.zarr"))).expect("read");
        let itk = &f["itk"];
        let size: Vec<usize> = numbers(&itk["size"]).into_iter().map(|x| x as usize).collect();
        let (origin, spacing, direction) =
            (numbers(&itk["origin"]), numbers(&itk["spacing"]), matrix(&itk["direction"]));
        let mm = f["spec"]["axes"]["x"]["mm_per_unit"].as_f64().expect("mm per unit");
        let theirs = corners([size[0], size[1], size[2]], |ijk| {
            std::array::from_fn(|r| {
                mm * (origin[r] + (0..3).map(|c| direction[r][c] * spacing[c] * ijk[c]).sum::<f64>())
            })
        });
        let rows = v.lps_from_index.rows();
        let ours = corners(v.dims, |ijk| {
            std::array::from_fn(|r| rows[r][3] + (0..3).map(|c| rows[r][c] * ijk[c]).sum::<f64>())
        });
        for (p, q) in ours.iter().zip(&theirs) {
            assert!((0..3).all(|a| (p[a] - q[a]).abs() <= 1e-9), "{name}: {ours:?} vs ITK's {theirs:?}");
        }
        compared += 1;
    }
    assert_eq!(compared, 8);
}

#[test]
fn assumptions_are_warned_about() {
    let read =
        |name: &str| LoadOptions::new().frame(0).open(data_dir().join(format!("{name}.ome.zarr"))).expect("read");
    let warned = |name: &str, what: &str| read(name).metadata.warnings.iter().any(|w| w.contains(what));
    // Orientations that name no patient axis: x, y, z placed as L, P, S.
    assert!(warned("v05_dorsal", "dorsal-to-ventral"));
    assert!(warned("v05_channel1", "no axis gives an anatomical orientation"));
    assert!(!warned("v04_i16", "orientation"), "v04_i16 is oriented");
    assert!(warned("v04_i16", "no unit: taken as mm"));
    assert!(!warned("v05_time_i16", "unit"), "v05_time_i16 gives millimeter");
    assert!(warned("v04_blosc_u8_levels", "full-resolution level of 2"));
    // Where RFC-4's text and ngff-zarr place voxel 0 apart (axes oriented other than x, y, z as L, P, S), the
    // warning gives the other position.
    assert!(warned("v05_u16_oriented", "RFC-4"));
    assert!(warned("v06_f32_ras", "(12.5, -30.25, 7)"));
    assert!(!warned("v04_i16", "RFC-4"), "L, P, S: both read it alike");
}

#[test]
fn bad_images_are_refused_naming_the_folder_and_the_problem() {
    let mut refused = 0;
    for f in reference() {
        let Some(keyword) = f["refuse"].as_str() else { continue };
        let name = f["name"].as_str().expect("name");
        let path = data_dir().join(format!("{name}.ome.zarr"));
        let e = warpbench_io::open(&path).expect_err(name);
        let text = e.to_string();
        assert!(text.starts_with(&path.display().to_string()), "{name}: {text}");
        assert!(text.contains(keyword), "{name}: {text} (wanted {keyword:?})");
        refused += 1;
    }
    assert_eq!(refused, 5);
    // A folder that is a Zarr store but no image, and a version not read.
    let dir = tempfile::tempdir().expect("tempdir");
    let store = dir.path().join("plain.zarr");
    std::fs::create_dir(&store).expect("mkdir");
    std::fs::write(store.join("zarr.json"), r#"{"zarr_format": 3, "node_type": "group", "attributes": {}}"#)
        .expect("write");
    assert_eq!(Format::detect(&store).expect("detect"), Format::OmeZarr);
    let e = ngff::read(&store, &mut LoadOptions::new()).expect_err("no image");
    assert!(e.to_string().contains("not an OME-Zarr image"), "{e}");
    std::fs::write(
        store.join("zarr.json"),
        r#"{"zarr_format": 3, "node_type": "group", "attributes": {"ome": {"version": "0.3", "multiscales": [{}]}}}"#,
    )
    .expect("write");
    let e = ngff::read(&store, &mut LoadOptions::new()).expect_err("0.3");
    assert!(e.to_string().contains("version 0.3"), "{e}");
    // bioformats2raw's layout (the image in the group `0` under a root that names the layout) opens its first image;
    // a plate (a screen of many images) is refused.
    let layout = dir.path().join("b2r.ome.zarr");
    copy_folder(&data_dir().join("v04_i16.ome.zarr"), &layout.join("0"));
    std::fs::write(layout.join(".zgroup"), r#"{"zarr_format": 2}"#).expect("write");
    std::fs::write(layout.join(".zattrs"), r#"{"bioformats2raw.layout": 3}"#).expect("write");
    let direct = warpbench_io::open(data_dir().join("v04_i16.ome.zarr")).expect("read");
    let nested = warpbench_io::open(&layout).expect("bioformats2raw's layout");
    assert_eq!((nested.dims, &nested.data, nested.lps_from_index), (direct.dims, &direct.data, direct.lps_from_index));
    std::fs::write(layout.join(".zattrs"), r#"{"plate": {"wells": []}}"#).expect("write");
    let e = warpbench_io::open(&layout).expect_err("a plate");
    assert!(e.to_string().contains("plate or well"), "{e}");
    // A shard of a million one-sample chunks would need a 16 MB index per shard: refused before `zarrs` reads one.
    let sharded = data_dir().join("v05_sharded_f64.ome.zarr");
    let copy = dir.path().join("sharded.ome.zarr");
    copy_folder(&sharded, &copy);
    let array = copy.join("scale0/image/zarr.json");
    let text = std::fs::read_to_string(&array).expect("read");
    let mut meta: Value = serde_json::from_str(&text).expect("JSON");
    meta["chunk_grid"]["configuration"]["chunk_shape"] = serde_json::json!([1000, 1000, 1000]);
    for codec in meta["codecs"].as_array_mut().expect("codecs") {
        if codec["name"] == "sharding_indexed" {
            codec["configuration"]["chunk_shape"] = serde_json::json!([1, 1, 1]);
        }
    }
    std::fs::write(&array, serde_json::to_string(&meta).expect("JSON")).expect("write");
    let e = ngff::read(&copy, &mut LoadOptions::new()).expect_err("huge shard index");
    assert!(e.to_string().contains("more chunks than warpbench indexes"), "{e}");
}

// --- Writing --------------------------------------------------------------------------------------------------------

/// Asserts that `written` holds `original`'s voxels where they are: each voxel centre of `original` is a voxel
/// centre of `written` (to 1e-9 of a voxel) with the same value and type, and the two grids have the same voxels.
fn assert_same_voxels_in_space(original: &warpbench_io::Volume, written: &warpbench_io::Volume, what: &str) {
    assert_eq!(written.sample_type(), original.sample_type(), "{what}: type");
    let sorted = |d: [usize; 3]| {
        let mut d = d.to_vec();
        d.sort_unstable();
        d
    };
    assert_eq!(sorted(written.dims), sorted(original.dims), "{what}: dims");
    let index_from_lps = written.lps_from_index.inverse().expect("invertible");
    let [ni, nj, nk] = original.dims;
    for k in 0..nk {
        for j in 0..nj {
            for i in 0..ni {
                let at = index_from_lps.apply_point(original.voxel_lps(i, j, k)).coords();
                let index = at.map(f64::round);
                assert!(
                    at.iter().zip(&index).all(|(a, r)| (a - r).abs() < 1e-9),
                    "{what}: voxel ({i}, {j}, {k}) lands at {at:?}, between voxels"
                );
                let [x, y, z] = index.map(|v| v as usize);
                let got = written.data.get_f64(written.offset(x, y, z));
                let want = original.data.get_f64(original.offset(i, j, k));
                assert!(got.to_bits() == want.to_bits(), "{what}: ({i}, {j}, {k}) {got} != {want}");
            }
        }
    }
}

/// Real volumes stored in other orders: RAS (NIfTI), FreeSurfer's LIA, MINC's RAS with anisotropic steps, ngff-zarr's permuted axes,
/// and a RAS-like 0.6 image.
const AXIS_ALIGNED: [&str; 5] = [
    "nifti/anatomical.nii",
    "mgh/conformed_lia_u8.mgz",
    "minc/small.mnc",
    "ngff/v05_u16_oriented.ome.zarr",
    "ngff/v06_f32_ras.ome.zarr",
];

#[test]
fn written_images_read_back_with_every_voxel_where_it_was_and_nothing_assumed() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (n, name) in AXIS_ALIGNED.iter().enumerate() {
        let source = data_dir().join("..").join(name);
        let original = LoadOptions::new().open(&source).unwrap_or_else(|e| panic!("{e}"));
        let out = dir.path().join(format!("out{n}.ome.zarr"));
        assert_eq!(warpbench_io::VolumeFileKind::of(&out), Some(warpbench_io::VolumeFileKind::OmeZarr));
        warpbench_io::write_volume(&out, &original).unwrap_or_else(|e| panic!("{name}: {e}"));
        let written = LoadOptions::new().open(&out).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(written.geometry_source, GeometrySource::OmeZarr);
        // Orientation and units are given, and ngff-zarr's reading and RFC-4's text place voxel 0 alike.
        assert_eq!(written.metadata.warnings, Vec::<String>::new(), "{name}");
        // The samples are stored along +L, +P, +S.
        let m = written.lps_from_index.linear();
        assert!((0..3).all(|r| (0..3).all(|c| r == c && m[(r, c)] > 0.0 || r != c && m[(r, c)] == 0.0)), "{name}");
        assert_same_voxels_in_space(&original, &written, name);
    }
}

#[test]
fn written_metadata_is_ome_zarr_0_5_with_rfc4_orientations() {
    let dir = tempfile::tempdir().expect("tempdir");
    let source = data_dir().join("../nifti/anatomical.nii");
    let original = LoadOptions::new().open(&source).expect("read");
    let out = dir.path().join("anatomical.ome.zarr");
    warpbench_io::write_volume(&out, &original).expect("write");
    let root: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("zarr.json")).expect("zarr.json")).expect("JSON");
    assert_eq!(root["zarr_format"], 3);
    assert_eq!(root["node_type"], "group");
    let ome = &root["attributes"]["ome"];
    assert_eq!(ome["version"], "0.5");
    let ms = &ome["multiscales"][0];
    assert_eq!(ms["name"], "anatomical");
    let axes: Vec<(&str, &str, &str, &str)> = ms["axes"]
        .as_array()
        .expect("axes")
        .iter()
        .map(|a| {
            (
                a["name"].as_str().expect("name"),
                a["type"].as_str().expect("type"),
                a["unit"].as_str().expect("unit"),
                a["orientation"]["value"].as_str().expect("orientation"),
            )
        })
        .collect();
    assert_eq!(
        axes,
        [
            ("z", "space", "millimeter", "inferior-to-superior"),
            ("y", "space", "millimeter", "anterior-to-posterior"),
            ("x", "space", "millimeter", "right-to-left"),
        ]
    );
    let dataset = &ms["datasets"][0];
    assert_eq!(dataset["path"], "0");
    // The scale is the spacing along S, P, L; the translation voxel 0's position: the corner of the RAS volume
    // nearest the right, anterior, inferior side.
    let spacing = original.spacing_mm();
    let lps = original.lps_from_index.linear();
    let along = |m: usize| (0..3).find(|&a| lps[(m, a)] != 0.0).expect("an axis along it");
    assert_eq!(numbers(&dataset["coordinateTransformations"][0]["scale"]), [2, 1, 0].map(|m| spacing[along(m)]));
    let corner_lps = |c: usize| {
        let [ni, nj, nk] = original.dims;
        let index = [ni, nj, nk].map(|n| [0, n - 1]);
        (0..8)
            .map(|b| original.voxel_lps(index[0][b & 1], index[1][b >> 1 & 1], index[2][b >> 2 & 1]).coords()[c])
            .fold(f64::INFINITY, f64::min)
    };
    assert_eq!(numbers(&dataset["coordinateTransformations"][1]["translation"]), [2, 1, 0].map(corner_lps));
    let array: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("0/zarr.json")).expect("array")).expect("JSON");
    assert_eq!(array["dimension_names"], serde_json::json!(["z", "y", "x"]));
    assert_eq!(array["data_type"], "int16", "anatomical.nii's samples keep their type");
}

#[test]
fn an_oblique_grid_is_refused_and_nothing_is_left() {
    let dir = tempfile::tempdir().expect("tempdir");
    let source = data_dir().join("../minc/oblique_i16.mnc");
    let original = LoadOptions::new().open(&source).expect("read");
    let out = dir.path().join("oblique.ome.zarr");
    let e = warpbench_io::write_volume(&out, &original).expect_err("oblique");
    let text = e.to_string();
    assert!(text.contains("oblique.ome.zarr") && text.contains("oblique grid") && text.contains('°'), "{text}");
    assert_eq!(std::fs::read_dir(dir.path()).expect("dir").count(), 0, "nothing written, no temporary left");
}

#[test]
fn a_zarr_store_is_replaced_whole_and_nothing_else_is() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out.ome.zarr");
    let first = LoadOptions::new().open(data_dir().join("../nifti/anatomical.nii")).expect("read");
    let second = LoadOptions::new().open(data_dir().join("../mgh/conformed_lia_u8.mgz")).expect("read");
    warpbench_io::write_volume(&out, &first).expect("first");
    // A file of the old store that the new one does not have must go with it.
    std::fs::write(out.join("0/c/stale"), b"old").expect("stale");
    warpbench_io::write_volume(&out, &second).expect("replacing");
    assert!(!out.join("0/c/stale").exists(), "the old store is gone whole");
    let written = LoadOptions::new().open(&out).expect("read back");
    assert_same_voxels_in_space(&second, &written, "replaced");
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("dir")
        .map(|e| e.expect("entry").file_name().into_string().expect("utf-8"))
        .collect();
    assert_eq!(names, ["out.ome.zarr"], "no temporary left beside it");

    // An empty folder is written into; a folder of anything else, or a file, is refused and left as it was.
    let empty = dir.path().join("empty.ome.zarr");
    std::fs::create_dir(&empty).expect("mkdir");
    warpbench_io::write_volume(&empty, &first).expect("an empty folder");
    let other = dir.path().join("notes.zarr");
    std::fs::create_dir(&other).expect("mkdir");
    std::fs::write(other.join("notes.txt"), b"mine").expect("write");
    let e = warpbench_io::write_volume(&other, &first).expect_err("another folder");
    assert!(e.to_string().contains("notes.zarr") && e.to_string().contains("does not replace"), "{e}");
    assert_eq!(std::fs::read(other.join("notes.txt")).expect("kept"), b"mine");
    let file = dir.path().join("file.zarr");
    std::fs::write(&file, b"a file").expect("write");
    let e = warpbench_io::write_volume(&file, &first).expect_err("a file");
    assert!(e.to_string().contains("file.zarr") && e.to_string().contains("not a folder"), "{e}");
    assert_eq!(std::fs::read(&file).expect("kept"), b"a file");
}

/// A volume of `dims` whose axis a runs along patient axis `axes[a]`, reversed where `signs` has bit a, with
/// `seed`'s samples of the type `kind` (0 u8, 1 i16, 2 u16, 3 f32).
fn axis_aligned_volume(
    dims: [usize; 3],
    axes: [usize; 3],
    signs: u8,
    spacing: [f64; 3],
    origin: [f64; 3],
    (kind, seed): (u8, u64),
) -> warpbench_io::Volume {
    use warpbench_io::VoxelData;
    let n = dims.iter().product::<usize>();
    let mut s = seed | 1;
    let mut next = || {
        s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        s >> 32
    };
    let data = match kind {
        0 => VoxelData::U8((0..n).map(|_| next() as u8).collect()),
        1 => VoxelData::I16((0..n).map(|_| next() as i16).collect()),
        2 => VoxelData::U16((0..n).map(|_| next() as u16).collect()),
        _ => VoxelData::F32((0..n).map(|_| (next() as f32 - 2e9) * 1e-3).collect()),
    };
    let mut linear = nalgebra::Matrix3::zeros();
    for a in 0..3 {
        linear[(axes[a], a)] = if signs >> a & 1 == 1 { -spacing[a] } else { spacing[a] };
    }
    let grid = warpbench_io::geometry::Transform::from_linear_translation(linear, origin);
    warpbench_io::Volume::new(Path::new("random"), dims, data, grid, GeometrySource::Assumed).expect("volume")
}

const PERMUTATIONS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 48, ..Default::default() })]

    /// Law: any grid along the patient axes, in any order and sense, of any sample type, is written and read back
    /// with every voxel where it was, the samples along +L, +P, +S, and nothing assumed.
    #[test]
    fn axis_aligned_volumes_round_trip_through_ome_zarr(
        dims in (1usize..6, 1usize..6, 1usize..5),
        permutation in 0usize..6,
        signs in 0u8..8,
        spacing in (0.05f64..5.0, 0.05f64..5.0, 0.05f64..5.0),
        origin in (-300f64..300.0, -300f64..300.0, -300f64..300.0),
        kind in 0u8..4,
        seed in proptest::prelude::any::<u64>(),
    ) {
        let volume = axis_aligned_volume(
            [dims.0, dims.1, dims.2],
            PERMUTATIONS[permutation],
            signs,
            [spacing.0, spacing.1, spacing.2],
            [origin.0, origin.1, origin.2],
            (kind, seed),
        );
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("v.ome.zarr");
        warpbench_io::write_volume(&out, &volume).expect("write");
        let written = LoadOptions::new().open(&out).expect("read back");
        proptest::prop_assert!(written.metadata.warnings.is_empty(), "{:?}", written.metadata.warnings);
        assert_same_voxels_in_space(&volume, &written, "random");
    }
}

// --- Displacement fields (OME-Zarr 0.6, RFC-5) ---------------------------------------------------------------------

fn field_reference() -> Value {
    let path = data_dir().join("field_reference.json");
    serde_json::from_str(&std::fs::read_to_string(&path).expect("field_reference.json")).expect("JSON")
}

#[test]
fn fields_read_to_what_ngff_zarr_gives_itk() {
    use warpbench_io::displacement::{FieldFormat, FieldSource, read_field_info};
    let reference = field_reference();
    let fields = reference["fields"].as_array().expect("fields");
    assert_eq!(fields.len(), 4);
    for f in fields {
        let name = f["name"].as_str().expect("name");
        let mm = f["mm_per_unit"].as_f64().expect("mm");
        let read = read_field_info(&data_dir().join(format!("{name}.ome.zarr"))).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(read.source, FieldSource::Field(FieldFormat::Ngff), "{name}");
        assert_eq!(read.direction, None, "{name}: a pull-back, as ITK takes it");
        let field = &read.field;
        let size = numbers(&f["size"]);
        assert_eq!(field.dims.map(|d| d as f64).to_vec(), size, "{name}");
        // ITK's grid (LPS), in the store's units: warpbench's in mm.
        let (origin, spacing, direction) = (numbers(&f["origin"]), numbers(&f["spacing"]), matrix(&f["direction"]));
        let m = field.lps_from_index.matrix();
        for r in 0..3 {
            assert!((m[(r, 3)] - origin[r] * mm).abs() < 1e-12, "{name}: origin");
            for c in 0..3 {
                assert!((m[(r, c)] - direction[r][c] * spacing[c] * mm).abs() < 1e-12, "{name}: ({r}, {c})");
            }
        }
        let vectors: Vec<Vec<f64>> = f["vectors"].as_array().expect("vectors").iter().map(numbers).collect();
        assert_eq!(vectors.len(), field.displacements_lps.len(), "{name}");
        for (n, (got, want)) in field.displacements_lps.iter().zip(&vectors).enumerate() {
            for a in 0..3 {
                let want = (want[a] * mm) as f32;
                assert!((got[a] - want).abs() <= 1e-6 * want.abs().max(1e-3), "{name}: voxel {n} {got:?}");
            }
        }
        let assumed = read.warnings.join("; ");
        if name == "field_plain" {
            assert!(assumed.contains("taken as mm") && assumed.contains("left, posterior and superior"), "{assumed}");
        } else {
            assert_eq!(read.warnings, Vec::<String>::new(), "{name}");
        }
    }
}

#[test]
fn fields_the_store_cannot_place_are_refused_and_a_field_is_no_volume() {
    let reference = field_reference();
    let bad = data_dir().join(format!("{}.ome.zarr", reference["refused"]["name"].as_str().expect("name")));
    let e = warpbench_io::displacement::read_field_info(&bad).expect_err("RAS-oriented");
    let text = e.to_string();
    assert!(
        text.contains("bad_field_ras") && text.contains("x left-to-right") && text.contains("two images"),
        "{text}"
    );
    let e = LoadOptions::new().open(data_dir().join("field_plain.ome.zarr")).expect_err("a field");
    assert!(e.to_string().contains("a displacement field") && e.to_string().contains("--field"), "{e}");
    // An image is no field.
    let e = warpbench_io::displacement::read_field_info(&data_dir().join("v04_i16.ome.zarr")).expect_err("image");
    assert!(e.to_string().contains("declares no displacements"), "{e}");
}

#[test]
fn written_fields_read_back_with_every_vector_where_it_was() {
    use warpbench_io::displacement::{FieldFormat, read_field_info, write_field};
    let dir = tempfile::tempdir().expect("tempdir");
    for (n, (axes, signs)) in [([0, 1, 2], 0b011), ([2, 0, 1], 0b101), ([1, 2, 0], 0)].into_iter().enumerate() {
        let volume = axis_aligned_volume([4, 3, 5], axes, signs, [1.5, 0.75, 2.0], [-40.0, 12.5, 3.0], (3, 7));
        let count = 60;
        let field: Vec<[f32; 3]> =
            (0..count).map(|i| [i as f32 * 0.5 - 9.0, 3.0 - i as f32 * 0.25, (i % 7) as f32]).collect();
        let out = dir.path().join(format!("f{n}.ome.zarr"));
        write_field(&out, FieldFormat::Ngff, volume.dims, &volume.lps_from_index, &field).expect("write");
        let read = read_field_info(&out).expect("read back");
        assert!(read.warnings.is_empty(), "{:?}", read.warnings);
        let back = &read.field;
        let index_from_lps = back.lps_from_index.inverse().expect("invertible");
        let [ni, nj, _] = volume.dims;
        for (at, d) in field.iter().enumerate() {
            let (i, j, k) = (at % ni, at / ni % nj, at / (ni * nj));
            let p = index_from_lps.apply_point(volume.voxel_lps(i, j, k)).coords().map(f64::round);
            let [x, y, z] = p.map(|v| v as usize);
            let got = back.displacements_lps[x + back.dims[0] * (y + back.dims[1] * z)];
            assert_eq!(got.map(f32::to_bits), d.map(f32::to_bits), "field {n}: voxel ({i}, {j}, {k})");
        }
    }
    // An oblique grid cannot be written; nothing is left.
    let oblique = LoadOptions::new().open(data_dir().join("../minc/oblique_i16.mnc")).expect("read");
    let n = oblique.dims.iter().product::<usize>();
    let out = dir.path().join("oblique.ome.zarr");
    let e = write_field(&out, FieldFormat::Ngff, oblique.dims, &oblique.lps_from_index, &vec![[0.0; 3]; n])
        .expect_err("oblique");
    assert!(e.to_string().contains("oblique grid"), "{e}");
    assert!(!out.exists());
}
