//! Every file in `tests/data/bad/` (truncated, corrupted, random, absurd dimensions) makes
//! `warpbench info` exit with code 2 and a message that names the file: no panic, no crash from a
//! huge allocation. The process runs under a 1 GiB address-space limit, so a reader that allocates
//! what a hostile header claims (1.9 GB or more) fails this test instead of passing by luck.

use std::path::Path;
use std::process::Command;

const ADDRESS_SPACE_LIMIT_KIB: u64 = 1024 * 1024;

#[test]
fn every_bad_file_is_a_clear_error_naming_it() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("tests/data/bad exists")
        .map(|e| e.expect("dir entry").path())
        .filter(|p| p.file_name().is_some_and(|n| n != "README.md"))
        .collect();
    files.sort();
    assert!(files.len() >= 15, "the corpus has only {} files", files.len());
    let mut failures = Vec::new();
    for file in &files {
        let name = file.file_name().expect("name").to_string_lossy().into_owned();
        // `ulimit -v` caps the address space of the reader, so an unchecked allocation cannot succeed.
        let out = Command::new("sh")
            .arg("-c")
            .arg(format!("ulimit -v {ADDRESS_SPACE_LIMIT_KIB} && exec \"$0\" info --quiet \"$1\""))
            .arg(env!("CARGO_BIN_EXE_warpbench"))
            .arg(file)
            .output()
            .expect("run warpbench");
        let stderr = String::from_utf8_lossy(&out.stderr);
        let ok = out.status.code() == Some(2) && stderr.contains(&name) && !stderr.contains("panicked");
        eprintln!("{} {name}: {}", if ok { "ok  " } else { "FAIL" }, stderr.trim());
        if !ok {
            failures.push(format!("{name}: exit {:?}: {}", out.status.code(), stderr.trim()));
        }
    }
    assert!(failures.is_empty(), "{} bad files were not rejected cleanly:\n{}", failures.len(), failures.join("\n"));
}
