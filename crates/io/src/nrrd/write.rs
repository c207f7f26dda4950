//! The NRRD writer: NRRD0004 in LPS, little-endian, gzip unless asked otherwise (see [`super`]).

use std::io::{self, Write};
use std::path::Path;

use crate::pargz::ParGzWriter;
use flate2::Compression;

use crate::error::{Error, Result};
use crate::volume::{SampleType, Volume, VoxelData};

/// Options for [`write_with`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NrrdWriteOptions {
    /// `encoding: gzip` when true (the default), `encoding: raw` when false.
    pub gzip: bool,
}

impl Default for NrrdWriteOptions {
    fn default() -> Self {
        Self { gzip: true }
    }
}

/// Writes `volume` as a gzip-compressed NRRD0004 file in LPS.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    write_with(path, volume, NrrdWriteOptions::default())
}

/// Writes `volume` as NRRD0004 in LPS, gzip-compressed or raw as `options` say.
pub fn write_with(path: &Path, volume: &Volume, options: NrrdWriteOptions) -> Result<()> {
    let n = crate::volume::checked_voxel_count(path, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(path, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    if !volume.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    let header = header_text(volume, options);
    crate::write_atomic(path, |w| {
        w.write_all(header.as_bytes())?;
        if options.gzip {
            let mut gz = ParGzWriter::new(w, Compression::default());
            write_samples(&mut gz, &volume.data)?;
            gz.finish()?;
            Ok(())
        } else {
            write_samples(w, &volume.data)
        }
    })
}

fn header_text(volume: &Volume, options: NrrdWriteOptions) -> String {
    use std::fmt::Write as _;
    let type_name = match volume.sample_type() {
        // teem's canonical names, which every NRRD reader knows.
        SampleType::U8 => "unsigned char",
        SampleType::I16 => "short",
        SampleType::U16 => "unsigned short",
        SampleType::F32 => "float",
    };
    let lps_from_index = &volume.lps_from_index;
    let l = lps_from_index.linear();
    let o = lps_from_index.translation();
    let col = |c: usize| format!("({:?},{:?},{:?})", l[(0, c)], l[(1, c)], l[(2, c)]);
    let [nx, ny, nz] = volume.dims;
    let mut h = String::from("NRRD0004\n# Complete NRRD file format specification at:\n");
    h.push_str("# http://teem.sourceforge.net/nrrd/format.html\n");
    let _ = writeln!(h, "type: {type_name}");
    h.push_str("dimension: 3\nspace: left-posterior-superior\n");
    let _ = writeln!(h, "sizes: {nx} {ny} {nz}");
    let _ = writeln!(h, "space directions: {} {} {}", col(0), col(1), col(2));
    h.push_str("kinds: domain domain domain\n");
    if volume.sample_type().bytes() > 1 {
        h.push_str("endian: little\n");
    }
    let _ = writeln!(h, "encoding: {}", if options.gzip { "gzip" } else { "raw" });
    let _ = writeln!(h, "space origin: ({:?},{:?},{:?})", o[0], o[1], o[2]);
    if let Some(desc) = &volume.metadata.description {
        let one_line: String = desc.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
        if !one_line.trim().is_empty() {
            let _ = writeln!(h, "content: {}", one_line.trim());
        }
    }
    h.push('\n');
    h
}

/// Writes the samples little-endian, a bounded chunk at a time (no full-size byte copy).
fn write_samples(w: &mut dyn Write, data: &VoxelData) -> io::Result<()> {
    data.try_for_each_le_chunk(|b| w.write_all(b))
}
