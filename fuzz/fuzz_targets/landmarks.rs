//! Any text given to the landmark readers (BigWarp CSV and JSON, Slicer .mrk.json, .fcsv, and the detection by
//! content) gives `Ok` or `Err`, never a panic. What a reader accepts, its writer writes and the reader reads back:
//! the same number of landmarks at the same positions (names may be normalised).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::landmarks::{
    BigWarpCsvOptions, LandmarkPair, SlicerPoint, detect_landmark_format, parse_bigwarp_csv, parse_bigwarp_json,
    parse_fcsv, parse_mrk_json, to_bigwarp_csv, to_bigwarp_json, to_fcsv, to_mrk_json,
};

fn pair_positions(pairs: &[LandmarkPair]) -> Vec<(Option<[f64; 3]>, Option<[f64; 3]>, bool)> {
    pairs.iter().map(|p| (p.moving.map(|q| q.coords()), p.fixed.map(|q| q.coords()), p.active)).collect()
}

fn point_positions(points: &[SlicerPoint]) -> Vec<Option<[f64; 3]>> {
    points.iter().map(|p| p.position.map(|q| q.coords())).collect()
}

type Parse<T> = fn(&Path, &str) -> warpbench_io::Result<Vec<T>>;
type Write<T> = fn(&Path, &[T]) -> warpbench_io::Result<String>;

/// Writes what was read and reads it back: it must read, to the same positions.
fn round_trip<T, K: PartialEq + std::fmt::Debug>(
    name: &Path,
    read: &[T],
    write: Write<T>,
    parse: Parse<T>,
    key: fn(&[T]) -> Vec<K>,
) {
    let Ok(text) = write(name, read) else { return };
    let back = parse(name, &text).unwrap_or_else(|e| panic!("written text does not read back: {e}\n{text}"));
    assert_eq!(key(&back), key(read), "written text reads back differently:\n{text}");
}

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let _ = detect_landmark_format(Path::new("fuzz.txt"), &text);
    for ras in [false, true] {
        let options = BigWarpCsvOptions { ras };
        let csv = Path::new("fuzz.csv");
        if let Ok(pairs) = parse_bigwarp_csv(csv, &text, options) {
            let text = to_bigwarp_csv(csv, &pairs, options);
            if let Ok(text) = text {
                let back = parse_bigwarp_csv(csv, &text, options)
                    .unwrap_or_else(|e| panic!("written CSV does not read back: {e}\n{text}"));
                assert_eq!(pair_positions(&back), pair_positions(&pairs), "CSV reads back differently:\n{text}");
            }
        }
        let json = Path::new("fuzz.json");
        if let Ok(pairs) = parse_bigwarp_json(json, &text, options) {
            if let Ok(text) = to_bigwarp_json(json, &pairs, options) {
                let back = parse_bigwarp_json(json, &text, options)
                    .unwrap_or_else(|e| panic!("written JSON does not read back: {e}\n{text}"));
                assert_eq!(pair_positions(&back), pair_positions(&pairs), "JSON reads back differently:\n{text}");
            }
        }
    }
    let mrk = Path::new("fuzz.mrk.json");
    if let Ok(points) = parse_mrk_json(mrk, &text) {
        round_trip(mrk, &points, to_mrk_json, parse_mrk_json, point_positions);
    }
    let fcsv = Path::new("fuzz.fcsv");
    if let Ok(points) = parse_fcsv(fcsv, &text) {
        round_trip(fcsv, &points, to_fcsv, parse_fcsv, point_positions);
    }
});
