//! Any text given to the landmark readers (BigWarp CSV, Slicer .mrk.json, .fcsv) gives `Ok` or `Err`,
//! never a panic.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::landmarks::{BigWarpCsvOptions, parse_bigwarp_csv, parse_fcsv, parse_mrk_json};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let _ = parse_bigwarp_csv(Path::new("fuzz.csv"), &text, BigWarpCsvOptions::default());
    let _ = parse_mrk_json(Path::new("fuzz.mrk.json"), &text);
    let _ = parse_fcsv(Path::new("fuzz.fcsv"), &text);
});
