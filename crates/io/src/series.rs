//! [`SeriesSummary`]: one DICOM series of a folder, in brief. Its own module because both the DICOM reader
//! ([`crate::dicom::list_series`]) and the error that asks for a choice ([`crate::ErrorKind::MultipleSeries`])
//! name it, and neither should import the other's module for it.

use std::fmt;

use serde::Serialize;

/// A short description of one DICOM series found in a folder.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SeriesSummary {
    pub series_instance_uid: String,
    pub series_number: Option<i64>,
    pub modality: String,
    pub description: String,
    pub files: usize,
}

impl fmt::Display for SeriesSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} (series {}, {}, \"{}\", {} files)",
            self.series_instance_uid,
            self.series_number.map_or_else(|| "?".to_string(), |n| n.to_string()),
            self.modality,
            self.description,
            self.files
        )
    }
}
