//! Any bytes given to the DICOM registration readers give `Ok` or `Err`, never a panic or a hang: as a Spatial
//! Registration (a starting transform) and as a Deformable Spatial Registration (a field). The readers take a path,
//! so each input is written to a file of this process's own first.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::env::temp_dir().join(format!("warpbench-fuzz-reg-{}.dcm", std::process::id()));
    if std::fs::write(&path, data).is_err() {
        return;
    }
    if let Ok(affine) = warpbench_io::dicom_reg::read_affine(&path) {
        let _ = affine.apply([12.5, -40.0, 7.0]);
    }
    let _ = warpbench_io::dicom_reg::read_field(&path);
    let _ = warpbench_io::dicom_reg::registration_kind(&path);
});
