//! Load benchmark (issue 2): a 512×512×300 uncompressed CT series must load in ≤ 3 s on the 2-core
//! machine, with peak memory ≤ 2× the decoded voxel data.
//!
//! The series is built once from the real lung CT fixture (`tests/data/nrrd/lung1_image.nrrd`, 48 slices
//! of 512², mirrored along k to 300 slices) and written, as scanners do, as unsigned 16-bit values with
//! RescaleIntercept −1024, into the git-ignored `data-cache/bench/`. Run:
//!
//! ```sh
//! cargo bench -p warpbench-io --bench load_dicom
//! ```
//!
//! A second case holds the same voxels as **one** multi-frame file (300 frames, NumberOfFrames and
//! SpacingBetweenSlices, 150 MiB): the case where the reader must not hold the file and a parsed copy
//! of its pixels at once.
//!
//! Peak memory is VmHWM from `/proc/self/status` after resetting it through `/proc/self/clear_refs`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use warpbench_io::dicom_write::{DicomSeriesOptions, write_series};
use warpbench_io::{LoadOptions, Modality, Volume, VoxelData};

const SLICES: usize = 300;
const RUNS: usize = 5;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn status_kib(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn build_series(dir: &Path) {
    let lung = warpbench_io::open(repo().join("tests/data/nrrd/lung1_image.nrrd")).expect("lung CT fixture");
    let VoxelData::I16(src) = &lung.data else { panic!("lung CT should be i16, is {:?}", lung.sample_type()) };
    let [nx, ny, nz] = lung.dims;
    let slice = nx * ny;
    let mut data = Vec::with_capacity(slice * SLICES);
    for k in 0..SLICES {
        // Mirror at the ends so neighbouring slices stay continuous: 0..47, 47..0, 0..47, ...
        let period = 2 * nz;
        let m = k % period;
        let src_k = if m < nz { m } else { period - 1 - m };
        data.extend_from_slice(&src[src_k * slice..(src_k + 1) * slice]);
    }
    let mut v = Volume::new(
        dir,
        [nx, ny, SLICES],
        VoxelData::I16(data),
        lung.lps_from_index,
        warpbench_io::GeometrySource::DicomPatient,
    )
    .expect("volume");
    v.modality = Modality::Ct;
    let opts = DicomSeriesOptions {
        rescale_intercept: -1024.0,
        series_description: "lung1 mirrored to 300 slices (benchmark)".into(),
        ..DicomSeriesOptions::default()
    };
    write_series(dir, &v, &opts).expect("write benchmark series");
}

/// Writes the series' voxels again as one classic multi-frame file (u16 + intercept −1024).
fn build_multiframe(series_dir: &Path, file: &Path) {
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::{tags, uids};
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
    let v = LoadOptions::new().open(series_dir).expect("series");
    let VoxelData::I16(hu) = &v.data else { panic!("series should load as i16") };
    let pixels: Vec<u8> = hu.iter().flat_map(|&x| ((i32::from(x) + 1024) as u16).to_le_bytes()).collect();
    let [nx, ny, nz] = v.dims;
    let m = v.lps_from_index.rows();
    let origin = format!("{}\\{}\\{}", m[0][3], m[1][3], m[2][3]);
    let str_el = |tag, vr, s: String| DataElement::new(tag, vr, PrimitiveValue::from(s));
    let obj = InMemDicomObject::from_element_iter([
        str_el(tags::SOP_CLASS_UID, VR::UI, uids::CT_IMAGE_STORAGE.into()),
        str_el(tags::SOP_INSTANCE_UID, VR::UI, "2.25.1".into()),
        str_el(tags::MODALITY, VR::CS, "CT".into()),
        str_el(tags::SERIES_INSTANCE_UID, VR::UI, "2.25.2".into()),
        str_el(tags::IMAGE_POSITION_PATIENT, VR::DS, origin),
        str_el(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, "1\\0\\0\\0\\1\\0".into()),
        str_el(tags::PIXEL_SPACING, VR::DS, format!("{}\\{}", m[1][1], m[0][0])),
        str_el(tags::SPACING_BETWEEN_SLICES, VR::DS, format!("{}", m[2][2])),
        str_el(tags::NUMBER_OF_FRAMES, VR::IS, nz.to_string()),
        DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
        str_el(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2".into()),
        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(ny as u16)),
        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(nx as u16)),
        DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16)),
        DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(16u16)),
        DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(15u16)),
        DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(0u16)),
        str_el(tags::RESCALE_INTERCEPT, VR::DS, "-1024".into()),
        str_el(tags::RESCALE_SLOPE, VR::DS, "1".into()),
        DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::from(pixels)),
    ]);
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .expect("meta")
        .write_to_file(file)
        .expect("write multi-frame file");
}

/// Loads `path` `RUNS` times; prints each run and returns (sorted times, worst peak ratio).
fn measure(label: &str, path: &Path) -> (Vec<f64>, f64) {
    let mut times = Vec::new();
    let mut worst_ratio = 0.0f64;
    for run in 0..RUNS {
        let _ = std::fs::write("/proc/self/clear_refs", "5");
        let rss_before = status_kib("VmRSS:").unwrap_or(0);
        let t = Instant::now();
        let v = LoadOptions::new().open(path).expect("load");
        let secs = t.elapsed().as_secs_f64();
        let peak = status_kib("VmHWM:").unwrap_or(0);
        let voxel_bytes = (v.data.len() * v.sample_type().bytes()) as f64;
        let growth_kib = peak.saturating_sub(rss_before);
        let ratio = (growth_kib * 1024) as f64 / voxel_bytes;
        worst_ratio = worst_ratio.max(ratio);
        println!(
            "{label} run {run}: {secs:.3} s, dims {:?} {}, peak RSS growth {:.0} MiB = {ratio:.2} x decoded voxels ({:.0} MiB)",
            v.dims,
            v.sample_type().name(),
            growth_kib as f64 / 1024.0,
            voxel_bytes / f64::from(1u32 << 20)
        );
        times.push(secs);
    }
    times.sort_by(f64::total_cmp);
    (times, worst_ratio)
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --benches` would pass other flags: only run on --bench.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let dir = repo().join("data-cache/bench/ct-512x512x300");
    if !dir.exists() {
        eprintln!("building {} ...", dir.display());
        std::fs::create_dir_all(dir.parent().expect("data-cache/bench")).expect("create data-cache/bench");
        build_series(&dir);
    }
    let multiframe = repo().join("data-cache/bench/ct-512x512x300-multiframe.dcm");
    if !multiframe.exists() {
        eprintln!("building {} ...", multiframe.display());
        build_multiframe(&dir, &multiframe);
    }
    for (label, path) in [("series of 300 files", dir.as_path()), ("one multi-frame file", multiframe.as_path())] {
        let (times, worst_ratio) = measure(label, path);
        println!(
            "load 512x512x300 CT, {label}: min {:.3} s, median {:.3} s, max {:.3} s over {RUNS} runs; \
             worst peak ratio {worst_ratio:.2}x (targets: <= 3 s, <= 2x)",
            times[0],
            times[RUNS / 2],
            times[RUNS - 1]
        );
    }
}
