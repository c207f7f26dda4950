//! OME-Zarr images (NGFF, the "next-generation file format" of the Open Microscopy Environment; a folder, usually
//! named `.ome.zarr`): the format of napari, BigWarp's and webknossos' Zarr exports, bioformats2raw, ngff-zarr and
//! ITK's `itk.imwrite(..., "x.ome.zarr")`. Versions 0.4 (Zarr v2) and 0.5 and 0.6 (Zarr v3) are read ([`read()`]);
//! the chunks are decoded by the `zarrs` crate (zstd, Blosc, gzip, sharding). A volume is written as 0.5
//! ([`write()`], module `write`: samples in LPS order, so that every reading of the placement agrees).
//!
//! # What is read
//!
//! The first multiscale's first dataset: the full-resolution level. Its axes must be three `space` axes named `x`,
//! `y` and `z`, perhaps one `time` axis (frames, chosen as for a 4-D NIfTI: [`crate::LoadOptions::frame`]), and any other
//! axis (a `channel`, say) with one sample. The samples are read in the array's order, so its last (fastest)
//! spatial axis is warpbench's i, the next j and the first k, and no sample moves.
//!
//! # Where it is
//!
//! OME-Zarr gives each axis a coordinate, `scale · index + translation` (the dataset's `scale` and `translation`,
//! then the multiscale's own, in 0.4 and 0.5; the dataset's sequence of them in 0.6), in the axis's `unit`. It
//! gives no patient space, so warpbench places the image as ngff-zarr (the reference implementation of RFC-4, the
//! proposal that adds anatomical orientation) converts it to an ITK image, whose space is LPS:
//! - the position of voxel 0 is (translation of `x`, of `y`, of `z`) in LPS;
//! - the direction of the axis named `x`, `y` or `z` is its RFC-4 `orientation` (`right-to-left` is +L,
//!   `anterior-to-posterior` +P, `inferior-to-superior` +S, the reverse ones negative) when all three axes give one
//!   of these six, else +L, +P and +S for `x`, `y` and `z`, with a warning that names the assumption;
//! - its spacing is its scale.
//!
//! Unlike ngff-zarr, which keeps the numbers as they are, warpbench converts every length unit to mm (a
//! `micrometer` is 0.001 mm); an axis without a unit is taken as mm, with a warning. Integer and float samples keep
//! or change their type as in every reader (`docs/formats.md`, "Sample types and rescale").
//!
//! # Modules
//! `meta` parses the metadata, `image` reads a volume, `write` writes one, `field` reads and writes RFC-5
//! displacement fields (OME-Zarr 0.6).

mod field;
mod image;
mod meta;
mod write;

pub use field::{read_field, read_field_capped, write_field};
pub use image::read;
pub use meta::looks_like_zarr;
pub use write::{MAX_OBLIQUE_SINE, check_grid, write};
