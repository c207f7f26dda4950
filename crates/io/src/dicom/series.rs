//! Series (step 2 of [`super`]): headers grouped by SeriesInstanceUID, and the one series to read.

use std::collections::BTreeMap;
use std::path::Path;

use super::header::Header;
use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::series::SeriesSummary;

/// Groups headers by SeriesInstanceUID, sorted by SeriesNumber (missing last) then UID.
pub(super) fn group_series(headers: Vec<Header>) -> Vec<Vec<Header>> {
    let mut by_uid: BTreeMap<String, Vec<Header>> = BTreeMap::new();
    for h in headers {
        by_uid.entry(h.series_uid.clone()).or_default().push(h);
    }
    let mut groups: Vec<Vec<Header>> = by_uid.into_values().collect();
    groups.sort_by(|a, b| {
        let key = |g: &[Header]| (g[0].series_number.is_none(), g[0].series_number, g[0].series_uid.clone());
        key(a).cmp(&key(b))
    });
    groups
}

pub(super) fn summary(group: &[Header]) -> SeriesSummary {
    let h = &group[0];
    SeriesSummary {
        series_instance_uid: h.series_uid.clone(),
        series_number: h.series_number,
        modality: h.modality.clone(),
        description: h.description.clone().unwrap_or_default(),
        files: group.len(),
    }
}

pub(super) fn select_series(label: &Path, headers: Vec<Header>, opts: &LoadOptions) -> Result<Vec<Header>> {
    let mut groups = group_series(headers);
    match &opts.series_instance_uid {
        Some(uid) => {
            let wanted = uid.trim();
            if let Some(i) = groups.iter().position(|g| g[0].series_uid == wanted) {
                return Ok(groups.swap_remove(i));
            }
            let found: Vec<String> = groups.iter().map(|g| summary(g).to_string()).collect();
            Err(Error::invalid(
                label,
                format!("no series with SeriesInstanceUID {wanted}; found:\n  {}", found.join("\n  ")),
            ))
        }
        None if groups.len() > 1 => {
            Err(Error::new(label, ErrorKind::MultipleSeries(groups.iter().map(|g| summary(g)).collect())))
        }
        None => Ok(groups.pop().unwrap_or_default()),
    }
}
