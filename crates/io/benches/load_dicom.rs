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
    let mut times = Vec::new();
    let mut worst_ratio = 0.0f64;
    for run in 0..RUNS {
        let _ = std::fs::write("/proc/self/clear_refs", "5");
        let rss_before = status_kib("VmRSS:").unwrap_or(0);
        let t = Instant::now();
        let v = LoadOptions::new().open(&dir).expect("load series");
        let secs = t.elapsed().as_secs_f64();
        let peak = status_kib("VmHWM:").unwrap_or(0);
        let voxel_bytes = (v.data.len() * v.sample_type().bytes()) as f64;
        let ratio = (peak.saturating_sub(rss_before) * 1024) as f64 / voxel_bytes;
        worst_ratio = worst_ratio.max(ratio);
        println!(
            "run {run}: {secs:.3} s, dims {:?} {}, peak RSS growth {:.0} MiB = {ratio:.2} x decoded voxels ({:.0} MiB)",
            v.dims,
            v.sample_type().name(),
            (peak.saturating_sub(rss_before)) as f64 / 1024.0,
            voxel_bytes / (1 << 20) as f64
        );
        times.push(secs);
        drop(v);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "load 512x512x300 CT series: min {:.3} s, median {:.3} s, max {:.3} s over {RUNS} runs; worst peak ratio {worst_ratio:.2}x (targets: <= 3 s, <= 2x)",
        times[0],
        times[RUNS / 2],
        times[RUNS - 1]
    );
}
