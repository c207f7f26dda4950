//! The errors the landmark formats share: a bad landmark, named by its 1-based index, its name and its line
//! ([`ErrorKind::Landmark`]), and a file of pairs or of one side given where the other is expected.

use std::path::Path;

use crate::error::{Error, ErrorKind};

/// The most characters of a landmark's name that a message quotes; a longer name is cut with `…`.
const MESSAGE_NAME_CHARS: usize = 60;

pub(super) fn landmark_error(
    path: &Path,
    index0: usize,
    name: &str,
    line: Option<u64>,
    problem: impl AsRef<str>,
) -> Error {
    let at = line.map(|l| format!(", line {l}")).unwrap_or_default();
    let cut;
    let name = match name.char_indices().nth(MESSAGE_NAME_CHARS) {
        Some((end, _)) => {
            cut = format!("{}…", &name[..end]);
            cut.as_str()
        }
        None => name,
    };
    Error::new(
        path,
        ErrorKind::Landmark { index: index0 + 1, problem: format!("(1-based, {name:?}{at}) {}", problem.as_ref()) },
    )
}

/// The error for a Slicer point list read as a file of pairs.
pub(super) fn slicer_one_side(path: &Path) -> Error {
    Error::unsupported(
        path,
        "a Slicer point list holds one side of the pairs (the points of one volume); give it together with the \
         list of the other volume, which is paired with it by order",
    )
}

/// The error for an elastix point file read as a file of pairs.
pub(super) fn elastix_one_side(path: &Path) -> Error {
    Error::unsupported(
        path,
        "an elastix point file holds the points of one image; give it together with the other image's file (elastix's \
         fixed and moving point sets), which is paired with it by order",
    )
}

/// The error for a BigWarp file read as a Slicer point list.
pub(super) fn bigwarp_not_slicer(path: &Path) -> Error {
    Error::unsupported(
        path,
        "a BigWarp landmarks file (pairs of points), not a Slicer point list: read it as a file of pairs",
    )
}
