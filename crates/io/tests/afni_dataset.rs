//! AFNI datasets against nibabel 5.4.2 and nitransforms 25.1.0 (`data-scripts/afni_fixtures.py`): AFNI's own files
//! from nibabel's test data (three gzip-compressed short sub-bricks; one short sub-brick with a scale factor) read to
//! nibabel's grid and values; 3dQwarp-style warps (RAI little-endian with `IJK_TO_DICOM_REAL`; L-P-S big-endian,
//! gzip-compressed, without it) read as the pull-back that takes each voxel centre where nitransforms maps it; and
//! what is not such a dataset, or is damaged, refused naming the file.

use std::path::{Path, PathBuf};

use warpbench_io::displacement::{FieldFormat, FieldSource, read_field_info};
use warpbench_io::{ErrorKind, Format, GeometrySource, LoadOptions, SampleType};

fn data(folder: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data").join(folder)
}

fn reference() -> serde_json::Value {
    let text = std::fs::read_to_string(data("afni_made").join("reference.json")).expect("the reference");
    serde_json::from_str(&text).expect("JSON")
}

fn matrix(v: &serde_json::Value) -> Vec<Vec<f64>> {
    v.as_array()
        .expect("rows")
        .iter()
        .map(|r| r.as_array().expect("a row").iter().map(|x| x.as_f64().expect("a number")).collect())
        .collect()
}

fn voxels(v: &serde_json::Value) -> Vec<[usize; 3]> {
    v.as_array()
        .expect("voxels")
        .iter()
        .map(|p| std::array::from_fn(|c| p[c].as_u64().expect("an index") as usize))
        .collect()
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("warpbench-afni-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");
    dir
}

/// Copies a dataset's two files into a fresh folder, the header passed through `edit`, the samples through `cut`.
fn copy_with(folder: &str, stem: &str, brik: &str, edit: impl Fn(&str) -> String, cut: usize) -> PathBuf {
    let dir = temp(&format!("{stem}-{cut}"));
    let head = std::fs::read_to_string(data(folder).join(format!("{stem}.HEAD"))).expect("the header");
    std::fs::write(dir.join(format!("{stem}.HEAD")), edit(&head)).expect("write");
    let bytes = std::fs::read(data(folder).join(format!("{stem}{brik}"))).expect("the samples");
    std::fs::write(dir.join(format!("{stem}{brik}")), &bytes[..bytes.len() - cut]).expect("write");
    dir.join(format!("{stem}.HEAD"))
}

#[test]
fn afnis_own_datasets_read_as_nibabel_reads_them() {
    let reference = reference();
    for (stem, case) in reference["datasets"].as_object().expect("datasets") {
        let want_grid = matrix(&case["lps_from_index"]);
        let bricks = case["sub_bricks"].as_u64().expect("a count") as usize;
        let at = voxels(&case["voxels"]);
        // Either file names the dataset.
        let brik = if stem == "example4d+orig" { ".BRIK.gz" } else { ".BRIK" };
        for name in [format!("{stem}.HEAD"), format!("{stem}{brik}")] {
            let path = data("afni").join(&name);
            assert_eq!(Format::detect(&path).expect("detect"), Format::Afni, "{name}");
            for t in 0..bricks {
                let mut opts = LoadOptions::new();
                if bricks > 1 {
                    opts.frame = Some(t);
                }
                let v = opts.open(&path).unwrap_or_else(|e| panic!("{e}"));
                let dims: Vec<u64> =
                    case["dims"].as_array().expect("dims").iter().filter_map(serde_json::Value::as_u64).collect();
                assert_eq!(v.dims.map(|n| n as u64).to_vec(), dims, "{name}");
                assert_eq!(v.geometry_source, GeometrySource::Afni);
                for (r, row) in want_grid.iter().enumerate().take(3) {
                    for (c, want) in row.iter().enumerate() {
                        let got = v.lps_from_index.rows()[r][c];
                        // The header's floats are printed to 7 digits; nibabel reads the same text.
                        assert!((got - want).abs() <= 1e-9 * want.abs().max(1.0), "{name} [{r}][{c}]: {got} {want}");
                    }
                }
                let labels: Vec<&str> =
                    case["labels"].as_array().expect("labels").iter().map(|l| l.as_str().expect("a label")).collect();
                assert_eq!(v.metadata.description.as_deref(), Some(labels[t]), "{name}");
                for (ijk, want) in at.iter().zip(case["values"][t].as_array().expect("values")) {
                    let n = ijk[0] + v.dims[0] * (ijk[1] + v.dims[1] * ijk[2]);
                    let (got, want) = (v.data.get_f64(n), want.as_f64().expect("a number"));
                    // A scale factor is applied in float64 and kept as float32.
                    assert!((got - want).abs() <= 1e-6 * want.abs(), "{name} sub-brick {t} at {ijk:?}: {got} {want}");
                }
                if stem == "scaled+tlrc" {
                    assert_eq!(v.sample_type(), SampleType::F32);
                    assert!(v.rescale.applied && (v.rescale.slope - 3.883_363e-08).abs() < 1e-15);
                } else {
                    assert_eq!(v.sample_type(), SampleType::I16);
                }
            }
        }
    }
}

#[test]
fn several_sub_bricks_ask_which_one() {
    let path = data("afni").join("example4d+orig.HEAD");
    let e = warpbench_io::open(&path).expect_err("three sub-bricks");
    assert!(matches!(e.kind, ErrorKind::FrameRequired { frames: 3 }), "{e}");
    let mut opts = LoadOptions::new();
    opts.frame = Some(3);
    let e = opts.open(&path).expect_err("out of range");
    assert!(e.to_string().contains("sub-brick 3 is out of range"), "{e}");
}

#[test]
fn each_warp_takes_its_voxels_where_nitransforms_takes_them() {
    let reference = reference();
    for (stem, case) in reference["warps"].as_object().expect("warps") {
        let path = data("afni_made").join(format!("{stem}.HEAD"));
        let read = read_field_info(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(read.source, FieldSource::Field(FieldFormat::Afni));
        assert!(read.warnings.is_empty(), "{:?}", read.warnings);
        let want_grid = matrix(&case["lps_from_index"]);
        let rows = read.field.lps_from_index.rows();
        for (r, row) in want_grid.iter().enumerate() {
            for (c, want) in row.iter().enumerate() {
                assert!((rows[r][c] - want).abs() < 1e-12, "{stem} [{r}][{c}]");
            }
        }
        let dims = read.field.dims;
        let mut worst = 0.0f64;
        let points = case["nitransforms_lps"].as_array().expect("points");
        let fixed = case["fixed_lps"].as_array().expect("points");
        for ((ijk, want), x) in voxels(&case["voxels"]).iter().zip(points).zip(fixed) {
            let n = ijk[0] + dims[0] * (ijk[1] + dims[1] * ijk[2]);
            let d = read.field.displacements_lps[n];
            for c in 0..3 {
                let got = x[c].as_f64().expect("a number") + f64::from(d[c]);
                worst = worst.max((got - want[c].as_f64().expect("a number")).abs());
            }
        }
        // nitransforms keeps the float32 deltas and adds them in float32.
        assert!(worst < 1e-4, "{stem}: {worst} mm");
    }
}

#[test]
fn a_dataset_that_is_not_a_warp_is_refused_as_a_field() {
    let e = read_field_info(&data("afni").join("example4d+orig.HEAD")).expect_err("not a warp");
    assert!(e.to_string().contains("not a 3dQwarp warp") && e.to_string().contains("#0"), "{e}");
}

#[test]
fn an_oblique_warp_is_refused() {
    let head = copy_with(
        "afni_made",
        "warp_rai+tlrc",
        ".BRIK",
        |h| {
            // IJK_TO_DICOM_REAL's first row tilted: no longer the cardinal grid.
            h.replacen(
                "name  = IJK_TO_DICOM_REAL\ncount = 12\n           2.5              0",
                "name  = IJK_TO_DICOM_REAL\ncount = 12\n           2.5            0.3",
                1,
            )
        },
        0,
    );
    let e = read_field_info(&head).expect_err("oblique");
    assert!(e.to_string().contains("oblique") && e.to_string().contains("warp_rai+tlrc.HEAD"), "{e}");
}

#[test]
fn damaged_datasets_are_refused_naming_the_file() {
    // The samples end early: the .BRIK is named.
    let head = copy_with("afni", "scaled+tlrc", ".BRIK", str::to_string, 100);
    let e = warpbench_io::open(&head).expect_err("short");
    assert!(matches!(e.kind, ErrorKind::Truncated(_)) && e.to_string().contains("scaled+tlrc.BRIK"), "{e}");

    // A type the reader does not take.
    let head = copy_with(
        "afni",
        "scaled+tlrc",
        ".BRIK",
        |h| h.replace("name = BRICK_TYPES\ncount = 1\n 1", "name = BRICK_TYPES\ncount = 1\n 5"),
        0,
    );
    let e = warpbench_io::open(&head).expect_err("complex");
    assert!(e.to_string().contains("type 5 (complex)") && e.to_string().contains("scaled+tlrc.HEAD"), "{e}");

    // A malformed attribute is named.
    let head = copy_with("afni", "scaled+tlrc", ".BRIK", |h| h.replace("count = 3\n 1 2 4", "count = 3\n 1 2 x"), 0);
    let e = warpbench_io::open(&head).expect_err("malformed");
    assert!(e.to_string().contains("ORIENT_SPECIFIC") && e.to_string().contains("'x'"), "{e}");

    // A count larger than the file allocates nothing.
    let head =
        copy_with("afni", "scaled+tlrc", ".BRIK", |h| h.replace("count = 3\n 1 2 4", "count = 999999999\n 1 2 4"), 0);
    let e = warpbench_io::open(&head).expect_err("huge count");
    assert!(e.to_string().contains("count 999999999"), "{e}");

    // nibabel's own damaged headers, beside example4d's samples: a string typed as integers, a complex sub-brick.
    for (stem, needle) in [
        ("bad_attribute+orig", "attribute BYTEORDER_STRING: value 1 ''LSB_FIRST~' is not a number"),
        ("bad_datatype+orig", "sub-brick 2 has type 5 (complex)"),
    ] {
        let dir = temp(stem);
        std::fs::copy(data("afni").join(format!("{stem}.HEAD")), dir.join(format!("{stem}.HEAD"))).expect("copy");
        std::fs::copy(data("afni").join("example4d+orig.BRIK.gz"), dir.join(format!("{stem}.BRIK.gz"))).expect("copy");
        let mut opts = LoadOptions::new();
        opts.frame = Some(0);
        let e = opts.open(dir.join(format!("{stem}.HEAD"))).expect_err("nibabel refuses it too");
        assert!(e.to_string().contains(needle) && e.to_string().contains(&format!("{stem}.HEAD")), "{e}");
    }

    // The header missing beside the samples, and the samples missing beside the header.
    let dir = temp("alone");
    std::fs::copy(data("afni").join("scaled+tlrc.BRIK"), dir.join("scaled+tlrc.BRIK")).expect("copy");
    let e = warpbench_io::open(dir.join("scaled+tlrc.BRIK")).expect_err("no header");
    assert!(e.to_string().contains("scaled+tlrc.HEAD is not beside it"), "{e}");
    std::fs::copy(data("afni").join("example4d+orig.HEAD"), dir.join("example4d+orig.HEAD")).expect("copy");
    let e = warpbench_io::open(dir.join("example4d+orig.HEAD")).expect_err("no samples");
    assert!(e.to_string().contains("no example4d+orig.BRIK"), "{e}");

    // A compression AFNI writes but this reader does not inflate.
    std::fs::copy(data("afni").join("scaled+tlrc.HEAD"), dir.join("scaled+tlrc.HEAD")).expect("copy");
    std::fs::rename(dir.join("scaled+tlrc.BRIK"), dir.join("scaled+tlrc.BRIK.bz2")).expect("rename");
    let e = warpbench_io::open(dir.join("scaled+tlrc.HEAD")).expect_err("bzip2");
    assert!(e.to_string().contains("bzip2") && e.to_string().contains("scaled+tlrc.BRIK.bz2"), "{e}");
}

#[test]
fn afnis_nifti_form_of_a_warp_is_the_same_warp() {
    let dataset = read_field_info(&data("afni_made").join("warp_rai+tlrc.HEAD")).expect("the dataset");
    let path = data("afni_made").join("warp_rai_WARP.nii.gz");
    assert!(warpbench_io::nifti::afni_extension::is_afni_warp(&path).expect("read"));
    let read = read_field_info(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((read.source, read.direction), (FieldSource::Field(FieldFormat::Afni), dataset.direction));
    assert_eq!(read.field.dims, dataset.field.dims);
    // The same float32 deltas, in the same (DICOM, LPS) order: nothing is negated.
    assert_eq!(read.field.displacements_lps, dataset.field.displacements_lps);
    let (a, b) = (read.field.lps_from_index.rows(), dataset.field.lps_from_index.rows());
    for (r, (x, y)) in a.iter().zip(&b).enumerate() {
        for c in 0..4 {
            // The NIfTI grid is float32.
            assert!((x[c] - y[c]).abs() < 1e-5, "[{r}][{c}]: {} {}", x[c], y[c]);
        }
    }
}

#[test]
fn a_nifti_warp_without_afnis_labels_is_refused() {
    // nitransforms' own AFNI writer keeps no extension: nothing says the 5-D array is a warp, nor in which frame.
    let path = data("afni_made").join("nitransforms_afni.nii.gz");
    assert!(!warpbench_io::nifti::afni_extension::is_afni_warp(&path).expect("read"));
    let e = read_field_info(&path).expect_err("no labels");
    assert!(
        e.to_string().contains("no AFNI extension labels it") && e.to_string().contains("nitransforms_afni"),
        "{e}"
    );
}

#[test]
fn afnis_own_names_open_the_dataset_and_its_sub_bricks() {
    let dir = data("afni");
    let frame = |t: usize| {
        let mut opts = LoadOptions::new();
        opts.frame = Some(t);
        opts.open(dir.join("example4d+orig.HEAD")).unwrap_or_else(|e| panic!("{e}"))
    };
    // The bare name, with or without AFNI's trailing dot, and a sub-brick selector on any form of the name.
    for (name, t) in [
        ("example4d+orig[1]", 1),
        ("example4d+orig.[0]", 0),
        ("example4d+orig.HEAD[2]", 2),
        ("example4d+orig.BRIK.gz[1]", 1),
        ("example4d+orig[$]", 2),
    ] {
        let path = dir.join(name);
        assert_eq!(Format::detect(&path).expect("detect"), Format::Afni, "{name}");
        let v = warpbench_io::open(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(v.data, frame(t).data, "{name}");
    }
    let v = warpbench_io::open(dir.join("scaled+tlrc")).expect("the bare name");
    assert_eq!(v.dims, [47, 54, 43]);
    // A selector out of range, one AFNI allows but that picks several, and a selector with --frame too.
    for (name, says) in [
        ("example4d+orig[3]", "sub-brick 3 is out of range"),
        ("example4d+orig[0..2]", "a list, a range or a label is not"),
    ] {
        let e = warpbench_io::open(dir.join(name)).expect_err(name);
        assert!(e.to_string().contains(says) && e.to_string().contains("example4d+orig.HEAD"), "{e}");
    }
    let mut opts = LoadOptions::new();
    opts.frame = Some(0);
    let e = opts.open(dir.join("example4d+orig[1]")).expect_err("twice");
    assert!(e.to_string().contains("choose one way"), "{e}");
    // A warp by its bare name; a warp with a selector is refused (it is read whole).
    let warp = data("afni_made");
    let read = read_field_info(&warp.join("warp_rai+tlrc")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(read.source, FieldSource::Field(FieldFormat::Afni));
    let e = read_field_info(&warp.join("warp_rai+tlrc[0]")).expect_err("a selector");
    assert!(e.to_string().contains("a warp is read whole"), "{e}");
    // A bare name with no dataset behind it says which header is missing.
    let e = warpbench_io::open(dir.join("missing+orig")).expect_err("no dataset");
    assert!(e.to_string().contains("missing+orig.HEAD"), "{e}");
}
