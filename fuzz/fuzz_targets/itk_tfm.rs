//! Any bytes given to ITK's text transform reader (one transform, or a composite's chain) and to the ANTs `.mat`
//! reader give `Ok` or `Err`, never a panic or a hang; a chain they read maps points (its inverse members by
//! Newton's method) without a panic and, on a small grid, samples to a field or refuses to.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::displacement::FieldSource;

mod chain_checks;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.tfm");
    let _ = warpbench_io::itk_tfm::parse_mat(name, data);
    let Ok(text) = std::str::from_utf8(data) else { return };
    let _ = warpbench_io::itk_tfm::parse(name, text);
    let Ok(chain) = warpbench_io::itk_chain::parse_text(name, text) else { return };
    chain_checks::exercise(&chain, name, FieldSource::ItkTransform);
});
