#!/usr/bin/env python3
"""OME-Zarr (NGFF) image volumes and what the specification and ngff-zarr read from each: tests/data/ngff/.

OME-Zarr stores an image as a Zarr group whose attributes hold `multiscales`; the first multiscale's first dataset
is the image at the highest resolution (a path to a Zarr array, relative to the group). 0.4 is Zarr v2 (`.zgroup`,
`.zattrs` with `multiscales` whose entry has `version`, arrays described by `.zarray`); 0.5 is Zarr v3 (`zarr.json`
everywhere, the OME metadata under `attributes.ome`, `ome.version`); 0.6 is Zarr v3 too, with the axes in
`coordinateSystems` and each dataset's `coordinateTransformations` one transformation with `input` / `output`,
here a `sequence` of a scale and a translation. Axes have `name`, `type` (space / time / channel) and an optional
`unit`; RFC-4 adds `orientation: {"type": "anatomical", "value": "left-to-right" ...}` to each space axis (the
axis' coordinate increases from left to right). A dataset's transformations are applied in order (scale then
translation: coordinate = scale * index + translation per axis); 0.4 / 0.5 may add multiscale-level
`coordinateTransformations` applied after the dataset's.

The files (each a folder NAME.ome.zarr; values are ramps with a different step along each axis plus a small
non-linear term, on 7 x 6 x 5 voxels, x fastest, unless said otherwise):

- written by ngff-zarr 0.50.0 (`itk_image_to_ngff_image` or `to_ngff_image`, `to_multiscales`, `to_ngff_zarr`)
  from ITK images with spacing (0.7, 1.3, 2.5) and origin (-12.5, 30.25, 7.0):
  - v04_i16: 0.4, int16, identity direction, zstd (ngff-zarr's default for Zarr v2), chunks 4 x 4 x 4 (8 chunks,
    the edge ones partial), dimension_separator "/"; dataset path `scale0/image` (ngff-zarr puts each level's array
    in a group of its own); ngff-zarr writes the LPS orientations (right-to-left, anterior-to-posterior,
    inferior-to-superior) for an identity direction, at 0.4 too, and a consolidated `.zmetadata`;
  - v05_u16_oriented: 0.5, uint16, ITK direction a signed permutation (columns (0,-1,0), (0,0,1), (-1,0,0)), which
    ngff-zarr writes as the orientations x posterior-to-anterior, y inferior-to-superior, z left-to-right; chunks
    (z, y, x) = (2, 3, 4);
  - v06_f32_ras: 0.6, float32, direction diag(-1, -1, 1) (x left-to-right, y posterior-to-anterior);
  - v04_blosc_u8_levels: 0.4, uint8, Blosc (lz4, clevel 5, byte shuffle), chunks (z, y, x) = (4, 6, 7): chunk
    0/0/0 is stored by Blosc as a plain copy (header flag 0x02: the ramp does not compress), chunk 1/0/0 (one
    slab, then three of padding) lz4-compressed; two levels (bin-shrink by 2: level 1 is `scale1/image`,
    2 x 3 x 3); the image is level 0;
  - v05_sharded_f64: 0.5, float64 values that float32 does not hold, `sharding_indexed` (inner chunks 2 x 2 x 2,
    shards 4 x 4 x 4, index at the end with crc32c; the edge shards partial). ngff-zarr's writer puts a shard's
    inner chunks in the order its threads finish them, which varies from run to run; the script rewrites each
    shard with the same encoded inner chunks in the order of the index (C order of the inner grid) and the
    index's crc32c recomputed (after checking ngff-zarr's);
  - v05_time_i16: 0.5, (t, z, y, x) of 3 frames (frame n = frame 0 + 1000 n), t unit second (scale 1.5,
    translation 0.25), space unit millimeter, no orientation; one chunk per frame;
  - v05_channel1: 0.5, uint8, (c, z, y, x) with one channel, no orientation;
  - v05_dorsal: 0.5, int16, orientations x left-to-right, y dorsal-to-ventral, z inferior-to-superior: not all
    LPS-compatible, so ngff-zarr falls back to the identity direction, silently (for the whole image: x's
    left-to-right is not used either); a reader should read it with that fallback and warn;
- made by this script with zarr-python 3.1.6 and group metadata written by hand:
  - v04_um_bigendian_i32: 0.4 (Zarr v2), dtype ">i4" (big-endian), no compressor, dimension_separator ".",
    chunks 8 x 6 x 4 (z, y, x: the chunk is longer than the array along z; Zarr stores edge chunks whole, the
    part past the array holding the fill value 0), dataset path `0`; unit micrometer on every axis; the dataset's
    scale (1250, 2600, 700) and translation (3500, 60500, -12500) (z, y, x) are followed by a multiscale-level
    scale (2, 0.5, 1), so that the combined geometry is (2500, 1300, 700) um and (7000, 30250, -12500) um:
    v04_i16's geometry in mm. int32 values float32 holds exactly (|v| < 2^24). ngff-zarr ignores the
    multiscale-level transformation;
  - v05_xyz_order_fill: 0.5 (Zarr v3), int8, axes stored in the order (x, y, z) (dimension_names too: x slowest
    in memory, z fastest), shape (7, 6, 5), chunks 4 x 4 x 4, gzip (level 6; the gzip header's mtime is zeroed
    after zarr-python writes it), fill_value 7 and the chunk at grid position (1, 0, 1) not written, so its
    12 voxels (x 4..6, y 0..3, z 4) are 7; the other values come from the same ramp and are never 7;
- refused (each keeps everything else valid; `refuse` is a word the error should contain):
  - bad_two_channels: 0.5 by ngff-zarr, (c, z, y, x) with 2 channels ("channel");
  - bad_rotation_06: v06_f32_ras's metadata with a rotation (30 degrees about z) between the scale and the
    translation of the dataset's sequence ("rotation"); ngff-zarr ignores the rotation silently;
  - bad_unit: 0.5 by ngff-zarr with unit "second" on the x axis (a UDUNITS unit, but not a length; the other
    axes millimeter) ("unit"). Not "furlong": UDUNITS-2 has it as a length, though NGFF's list of space units
    does not;
  - bad_axis_names: 0.5 made by the script, three space axes named a, b, c without orientation, int16, one
    chunk of 8 x 8 x 8 ("axis names"); ngff-zarr takes the axis named c for its channel axis;
  - bad_truncated_chunk: 0.5 by ngff-zarr (int16, zstd, chunks 4) whose chunk c/0/0/0 is cut to half its bytes
    ("chunk").

reference.json: {"readers": {"ngff-zarr", "zarr", "numcodecs", "itk", "numpy"}, "files": [entry, ...]}, floats
as Python's repr (round-trip exact). Each entry:
- `name` (the folder), `version` (NGFF), `zarr_format` (2 / 3), `dtype` (numpy's name of the stored type, e.g.
  "int32" for ">i4"), `zarr_dtype` (as the array metadata says: ">i4", "int16"), `array_axes`: [{name, type,
  unit, orientation}, ...] in the array's order, slowest first (null for a missing unit / orientation; the
  orientation is its `value`), `shape` (array order), `chunks` (the chunk grid's shape; for a sharded array the
  shard), `codecs` (v2: the compressor's id, [] when null; v3: the codec names, a sharding codec as
  "sharding_indexed(inner codecs)"), `level0_path`, `frames` (the number of t frames, null without t).
- `spec`: what the specification gives, from the JSON this script wrote, without ngff-zarr. `axes`: for each space
  axis name {scale, translation (dataset then multiscale-level transformations combined), unit, mm_per_unit (1 when
  no unit), orientation, lps_direction}; `time` (null without t): {name, scale, translation, unit};
  `direction_from` ("orientation" when all three space axes have one of the six LPS-compatible orientations
  (right-to-left = +L = (1, 0, 0), anterior-to-posterior = (0, 1, 0), inferior-to-superior = (0, 0, 1), the
  reverse ones negative), else "name": x (1, 0, 0), y (0, 1, 0), z (0, 0, 1)); `lps_from_index_mm`: the 4 x 4
  row-major matrix mapping (i, j, k, 1) to LPS mm, i the array's last (fastest) space axis, j the middle one, k the
  first; the column of an axis is lps_direction * scale * mm_per_unit and the translation column is the sum over
  the axes of lps_direction * translation * mm_per_unit (RFC-4: an axis' coordinate increases in its orientation's
  direction, so the LPS point is the sum of each axis' direction times its coordinate, scale * index +
  translation; lengths are computed exactly, from the unit's decimal factor, and rounded once to float64, so
  700 um is 0.7 mm, not 0.7000000000000001; compare with a relative tolerance of about 1e-15);
  `lps_from_index_mm_ngff_zarr`: the same matrix with the translation column ngff-zarr gives, (translation_x,
  translation_y, translation_z) * mm_per_unit taken as LPS whatever the orientations (ngff-zarr's ITK convention:
  origin = the translations by axis name, in LPS); `translations_agree`: whether the two translation columns are
  equal (they are when the directions are the identity, and differ for v05_u16_oriented and v06_f32_ras). The
  linear parts are always equal.
- `itk`: what `ngff_image_to_itk_image` (ngff-zarr's conversion; its default itkwasm image) gives for the level-0
  image (frame 0, channel 0): {size, origin, spacing, direction (row-major 3 x 3)} as it gives them, no unit
  scaling, ITK's x, y, z order (axes taken by name); null where ngff-zarr cannot read the file.
- `itk_values_agree`: whether ngff-zarr's image holds, at ITK index (x, y, z) (x fastest in its buffer, as ITK
  reads one), the value zarr-python reads at the array index of those names, in every frame; false for
  v05_xyz_order_fill (ngff-zarr hands ITK the buffer in the array's (x, y, z) order as if it were (z, y, x));
  null where not compared.
- `values`: one entry per t frame (one for a 3-D image), of the values zarr-python's `open_array` reads (fill
  values included), channel 0, in our order (i fastest: the array's last space axis fastest, i.e. the C order of
  the space axes in storage order; z fastest for v05_xyz_order_fill): {sha256 (of the values as little-endian
  float64), sha256_f32 (cast to float32, stored little-endian), sum (math.fsum, correctly rounded), min, max}.
- `refuse`: for a file a reader must refuse, a word its error should contain, else null; `warn`: for a file read
  with a warning, a word the warning should contain ("orientation" for v05_dorsal), else null. For a refused file
  `spec`, `values` and `itk_values_agree` are null (the script's own reading of the metadata refuses it with a
  message holding that word; bad_truncated_chunk's is zarr-python's decoding error), while `itk` still says what
  ngff-zarr makes of it where that is a 3-D image.
- `ngff_zarr`: a sentence on what ngff-zarr 0.50.0 does with the file; `note`: what the file exercises.

Checks (asserted): the spec matrices are computed from the written JSON; for every file ngff-zarr reads and the spec
accepts, lps_from_index_mm_ngff_zarr equals ngff-zarr's ITK geometry (origin, spacing, direction, each ITK axis'
column moved to the array axis of its name, lengths times mm_per_unit; for v04_um_bigendian_i32 with the
multiscale-level scale applied on top of ngff-zarr's, which leaves it out), and lps_from_index_mm has the same
linear part; ngff-zarr's values equal zarr-python's where itk_values_agree is true; the values match the arrays
the script wrote (fill values included).

Determinism: a rerun writes the same bytes (zstd, Blosc and gzip are deterministic; gzip's mtime is zeroed; the
shards are put in index order). The script removes each fixture folder before writing it again.

`--check DIR...` writes nothing: it prints, as JSON, the same reading of each OME-Zarr folder (refuse / warn /
note left null; `refused`, the script's reason for refusing it or null, and `warnings` added), e.g. one
warpbench wrote.

Usage, from the repository root (a venv with ngff-zarr 0.50.0, zarr 3.1.6, numcodecs 0.16.6, itk 5.4.7,
itkwasm, numpy 2.4.6, dask):

    /tmp/ngffvenv/bin/python data-scripts/ngff_fixtures.py [--out tests/data/ngff]
    /tmp/ngffvenv/bin/python data-scripts/ngff_fixtures.py --check some.ome.zarr
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import shutil
import sys
import warnings
from fractions import Fraction
from pathlib import Path

import itk
import ngff_zarr as nz
import numcodecs
import numpy as np
import zarr
from ngff_zarr.rfc4 import AnatomicalOrientation, AnatomicalOrientationValues
from zarr.codecs import GzipCodec
from zarr.storage import LocalStore

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "ngff"

SIZE = (7, 6, 5)  # x, y, z (ITK order)
SPACING = (0.7, 1.3, 2.5)
ORIGIN = (-12.5, 30.25, 7.0)

# Millimetres per NGFF length unit (the UDUNITS-2 names the specification lists for space axes).
MM_PER_UNIT = {
    "angstrom": "1e-7", "attometer": "1e-15", "centimeter": "10", "decimeter": "100", "exameter": "1e21",
    "femtometer": "1e-12", "foot": "304.8", "gigameter": "1e12", "hectometer": "1e5", "inch": "25.4",
    "kilometer": "1e6", "megameter": "1e9", "meter": "1e3", "micrometer": "1e-3", "mile": "1609344",
    "millimeter": "1", "nanometer": "1e-6", "parsec": "3.0856775814913673e19", "petameter": "1e18",
    "picometer": "1e-9", "terameter": "1e15", "yard": "914.4", "yoctometer": "1e-21", "yottameter": "1e27",
    "zeptometer": "1e-18", "zettameter": "1e24",
}  # exact decimals: lengths in mm are computed exactly (fractions) and rounded once
LPS_OF_ORIENTATION = {
    "right-to-left": (1.0, 0.0, 0.0), "left-to-right": (-1.0, 0.0, 0.0),
    "anterior-to-posterior": (0.0, 1.0, 0.0), "posterior-to-anterior": (0.0, -1.0, 0.0),
    "inferior-to-superior": (0.0, 0.0, 1.0), "superior-to-inferior": (0.0, 0.0, -1.0),
}
LPS_OF_NAME = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class Refused(Exception):
    """The script's own reading refuses the file."""


# ---------------------------------------------------------------------------------------------------- volumes


def ramp(dtype, base, steps, wiggle, size=SIZE) -> np.ndarray:
    """A (z, y, x) array: base + steps . (x, y, z) + wiggle * ((x*y + 2*z*x) % 5); different along each axis."""
    z, y, x = np.indices(size[::-1], dtype=np.float64)
    v = base + steps[0] * x + steps[1] * y + steps[2] * z + wiggle * ((x * y + 2 * z * x) % 5)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        assert info.min <= v.min() and v.max() <= info.max
        v = np.rint(v)
    return v.astype(dtype)


def vol_i16() -> np.ndarray:
    return ramp(np.int16, -20000, (900, 4100, 6500), 17)


def itk_image(arr: np.ndarray, direction) -> object:
    img = itk.image_from_array(np.ascontiguousarray(arr))
    img.SetSpacing(SPACING)
    img.SetOrigin(ORIGIN)
    img.SetDirection(itk.matrix_from_array(np.asarray(direction, dtype=np.float64)))
    return img


def geometry_image(arr: np.ndarray, dims: tuple, extra_scale=None, extra_translation=None, units=None):
    """An NgffImage of `arr` on the fixtures' grid, made directly (for t / c axes, units, orientations)."""
    scale = {"x": SPACING[0], "y": SPACING[1], "z": SPACING[2], **(extra_scale or {})}
    translation = {"x": ORIGIN[0], "y": ORIGIN[1], "z": ORIGIN[2], **(extra_translation or {})}
    return nz.to_ngff_image(arr, dims=dims, scale={d: scale[d] for d in dims if d != "c"},
                            translation={d: translation[d] for d in dims if d != "c"}, axes_units=units)


# ---------------------------------------------------------------------------------------------------- writing


def write_ngff(path: Path, multiscales, version: str, **kwargs) -> None:
    if path.exists():
        shutil.rmtree(path)
    nz.to_ngff_zarr(str(path), multiscales, version=version, **kwargs)


def dump_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=4) + "\n")


def zero_gzip_mtimes(folder: Path) -> None:
    for p in sorted(folder.rglob("*")):
        raw = p.read_bytes() if p.is_file() else b""
        if raw[:3] == b"\x1f\x8b\x08":
            p.write_bytes(raw[:4] + bytes(4) + raw[8:])


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli, reflected 0x82F63B78), as Zarr's crc32c codec computes it."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def normalise_shards(array_dir: Path, inner_per_shard: int) -> None:
    """ngff-zarr's writer puts a shard's inner chunks in the order its threads finish them; rewrite each shard with
    them in the order of its index (C order of the inner grid), the same encoded bytes, and the index (offset,
    nbytes little-endian uint64 pairs, then its crc32c) at the end."""
    empty = 2**64 - 1
    for shard in sorted(p for p in (array_dir / "c").rglob("*") if p.is_file()):
        raw = shard.read_bytes()
        index = raw[-(16 * inner_per_shard + 4):]
        assert int.from_bytes(index[-4:], "little") == crc32c(index[:-4]), shard
        pairs = np.frombuffer(index[:-4], dtype="<u8").reshape(-1, 2)
        body, new = b"", []
        for offset, nbytes in pairs.tolist():
            if offset == empty and nbytes == empty:
                new.append((empty, empty))
                continue
            new.append((len(body), nbytes))
            body += raw[offset : offset + nbytes]
        table = np.asarray(new, dtype="<u8").tobytes()
        shard.write_bytes(body + table + crc32c(table).to_bytes(4, "little"))


def make_v04_i16(out: Path) -> np.ndarray:
    arr = vol_i16()
    ms = nz.to_multiscales(nz.itk_image_to_ngff_image(itk_image(arr, np.eye(3))), scale_factors=[], chunks=4)
    write_ngff(out / "v04_i16.ome.zarr", ms, "0.4")
    return arr


def make_v05_u16_oriented(out: Path) -> np.ndarray:
    arr = ramp(np.uint16, 1000, (1100, 2300, 9000), 13)
    direction = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns (0,-1,0) (0,0,1) (-1,0,0)
    ng = nz.itk_image_to_ngff_image(itk_image(arr, direction))
    ms = nz.to_multiscales(ng, scale_factors=[], chunks={"z": 2, "y": 3, "x": 4})
    write_ngff(out / "v05_u16_oriented.ome.zarr", ms, "0.5")
    return arr


def make_v06_f32_ras(out: Path) -> np.ndarray:
    arr = ramp(np.float32, -1234.5, (12.25, 101.125, 997.0625), 0.375)
    ng = nz.itk_image_to_ngff_image(itk_image(arr, np.diag([-1.0, -1.0, 1.0])))
    write_ngff(out / "v06_f32_ras.ome.zarr", nz.to_multiscales(ng, scale_factors=[], chunks=4), "0.6")
    return arr


def make_v04_blosc_u8_levels(out: Path) -> np.ndarray:
    arr = ramp(np.uint8, 3, (5, 11, 37), 1)
    ng = nz.itk_image_to_ngff_image(itk_image(arr, np.eye(3)))
    ms = nz.to_multiscales(ng, scale_factors=[2], chunks={"z": 4, "y": 6, "x": 7},
                           method=nz.Methods.ITKWASM_BIN_SHRINK)
    blosc = numcodecs.Blosc(cname="lz4", clevel=5, shuffle=numcodecs.Blosc.SHUFFLE)
    folder = out / "v04_blosc_u8_levels.ome.zarr"
    write_ngff(folder, ms, "0.4", compressor=blosc)
    # Blosc's header flags (byte 2): 0x01 byte shuffle, 0x02 stored as a plain copy, bits 5-7 the codec (1: lz4).
    flags = [(folder / "scale0" / "image" / k).read_bytes()[2] for k in ("0/0/0", "1/0/0")]
    assert flags == [0x23, 0x21], flags
    return arr


def make_v05_sharded_f64(out: Path) -> np.ndarray:
    arr = ramp(np.float64, -3.3, (0.1, -7.7, 1000.01), 1e-9)
    assert not np.array_equal(arr.astype(np.float32).astype(np.float64), arr)
    ng = nz.itk_image_to_ngff_image(itk_image(arr, np.eye(3)))
    folder = out / "v05_sharded_f64.ome.zarr"
    write_ngff(folder, nz.to_multiscales(ng, scale_factors=[], chunks=2), "0.5", chunks_per_shard=2)
    normalise_shards(folder / "scale0" / "image", 8)
    return arr


def make_v05_time_i16(out: Path) -> np.ndarray:
    frame = ramp(np.int16, -15000, (700, 3100, 5200), 11)
    arr = np.stack([frame + np.int16(1000 * n) for n in range(3)])
    units = {"t": "second", "z": "millimeter", "y": "millimeter", "x": "millimeter"}
    ng = geometry_image(arr, ("t", "z", "y", "x"), {"t": 1.5}, {"t": 0.25}, units)
    ms = nz.to_multiscales(ng, scale_factors=[], chunks={"t": 1, "z": 8, "y": 8, "x": 8})
    write_ngff(out / "v05_time_i16.ome.zarr", ms, "0.5")
    return arr


def make_v05_channel1(out: Path) -> np.ndarray:
    arr = ramp(np.uint8, 9, (4, 13, 31), 2)[None]
    ng = geometry_image(arr, ("c", "z", "y", "x"))
    write_ngff(out / "v05_channel1.ome.zarr", nz.to_multiscales(ng, scale_factors=[], chunks=8), "0.5")
    return arr


def make_v05_dorsal(out: Path) -> np.ndarray:
    arr = ramp(np.int16, -9000, (300, 1700, 2900), 7)
    V = AnatomicalOrientationValues
    orientation = {"x": AnatomicalOrientation(value=V.left_to_right),
                   "y": AnatomicalOrientation(value=V.dorsal_to_ventral),
                   "z": AnatomicalOrientation(value=V.inferior_to_superior)}
    ng = geometry_image(arr, ("z", "y", "x"))
    ms = nz.to_multiscales(ng, scale_factors=[], chunks=8, orientation=orientation)
    write_ngff(out / "v05_dorsal.ome.zarr", ms, "0.5")
    return arr


def make_v04_um_bigendian_i32(out: Path) -> np.ndarray:
    arr = ramp(np.int32, -5_000_000, (12345, 234567, 3456789), 3)
    assert np.abs(arr).max() < 2**24
    folder = out / "v04_um_bigendian_i32.ome.zarr"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    a = zarr.create_array(store=LocalStore(folder / "0"), shape=arr.shape, chunks=(8, 6, 4), dtype=">i4",
                          zarr_format=2, compressors=None, fill_value=0)
    a[...] = arr
    dump_json(folder / ".zgroup", {"zarr_format": 2})
    axes = [{"name": n, "type": "space", "unit": "micrometer"} for n in ("z", "y", "x")]
    dump_json(folder / ".zattrs", {"multiscales": [{
        "version": "0.4",
        "name": "v04_um_bigendian_i32",
        "axes": axes,
        "datasets": [{"path": "0", "coordinateTransformations": [
            {"type": "scale", "scale": [1250.0, 2600.0, 700.0]},
            {"type": "translation", "translation": [3500.0, 60500.0, -12500.0]},
        ]}],
        "coordinateTransformations": [{"type": "scale", "scale": [2.0, 0.5, 1.0]}],
    }]})
    return arr


XYZ_MISSING_CHUNK = (1, 0, 1)  # grid position (x, y, z) of the chunk left unwritten


def make_v05_xyz_order_fill(out: Path) -> np.ndarray:
    zyx = ramp(np.int8, -100, (4, 6, 18), 2)  # all even: never the fill value
    xyz = np.ascontiguousarray(zyx.transpose(2, 1, 0))
    assert not (xyz == 7).any()
    folder = out / "v05_xyz_order_fill.ome.zarr"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    a = zarr.create_array(store=LocalStore(folder / "0"), shape=xyz.shape, chunks=(4, 4, 4), dtype="int8",
                          zarr_format=3, compressors=[GzipCodec(level=6)], fill_value=7,
                          dimension_names=["x", "y", "z"])
    expected = xyz.copy()
    for pos in np.ndindex(2, 2, 2):
        sl = tuple(slice(4 * p, 4 * p + 4) for p in pos)
        if pos == XYZ_MISSING_CHUNK:
            expected[sl] = 7
            assert expected[sl].size == 12
            continue
        a[sl] = xyz[sl]
    zero_gzip_mtimes(folder / "0")
    dump_json(folder / "zarr.json", {"zarr_format": 3, "node_type": "group", "attributes": {"ome": {
        "version": "0.5",
        "multiscales": [{
            "name": "v05_xyz_order_fill",
            "axes": [{"name": n, "type": "space", "unit": "millimeter"} for n in ("x", "y", "z")],
            "datasets": [{"path": "0", "coordinateTransformations": [
                {"type": "scale", "scale": list(SPACING)},
                {"type": "translation", "translation": list(ORIGIN)},
            ]}],
        }],
    }}})
    return expected


def make_bad(out: Path) -> None:
    # Two channels.
    arr2 = np.stack([vol_i16(), vol_i16() // 2])
    ng = geometry_image(arr2, ("c", "z", "y", "x"))
    write_ngff(out / "bad_two_channels.ome.zarr", nz.to_multiscales(ng, scale_factors=[], chunks=8), "0.5")

    # A rotation in a 0.6 sequence: v06_f32_ras's metadata, rewritten.
    src = out / "v06_f32_ras.ome.zarr"
    dst = out / "bad_rotation_06.ome.zarr"
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    meta = json.loads((dst / "zarr.json").read_text())
    seq = meta["attributes"]["ome"]["multiscales"][0]["datasets"][0]["coordinateTransformations"][0]
    assert seq["type"] == "sequence" and [t["type"] for t in seq["transformations"]] == ["scale", "translation"]
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    # The axes are (z, y, x): a rotation about z turns y and x.
    seq["transformations"].insert(1, {"type": "rotation", "rotation": [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]})
    dump_json(dst / "zarr.json", meta)

    # A space unit that is not a length.
    units = {"z": "millimeter", "y": "millimeter", "x": "second"}
    ng = geometry_image(vol_i16(), ("z", "y", "x"), units=units)
    write_ngff(out / "bad_unit.ome.zarr", nz.to_multiscales(ng, scale_factors=[], chunks=8), "0.5")

    # Space axes named a, b, c.
    folder = out / "bad_axis_names.ome.zarr"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    a = zarr.create_array(store=LocalStore(folder / "0"), shape=(5, 6, 7), chunks=(8, 8, 8), dtype="int16",
                          zarr_format=3, dimension_names=["a", "b", "c"])
    a[...] = vol_i16()
    dump_json(folder / "zarr.json", {"zarr_format": 3, "node_type": "group", "attributes": {"ome": {
        "version": "0.5",
        "multiscales": [{
            "name": "bad_axis_names",
            "axes": [{"name": n, "type": "space", "unit": "millimeter"} for n in ("a", "b", "c")],
            "datasets": [{"path": "0", "coordinateTransformations": [
                {"type": "scale", "scale": [2.5, 1.3, 0.7]},
                {"type": "translation", "translation": [7.0, 30.25, -12.5]},
            ]}],
        }],
    }}})

    # A chunk cut short.
    ng = nz.itk_image_to_ngff_image(itk_image(vol_i16(), np.eye(3)))
    folder = out / "bad_truncated_chunk.ome.zarr"
    write_ngff(folder, nz.to_multiscales(ng, scale_factors=[], chunks=4), "0.5")
    chunk = folder / "scale0" / "image" / "c" / "0" / "0" / "0"
    raw = chunk.read_bytes()
    chunk.write_bytes(raw[: len(raw) // 2])


# ---------------------------------------------------------------------------------------------------- reading


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def floats(a) -> list:
    return [float(x) for x in np.asarray(a, dtype=np.float64).ravel()]


def read_metadata(folder: Path) -> dict:
    """The group's OME metadata, version and Zarr format, and the level-0 array's metadata, from the JSON files."""
    if (folder / "zarr.json").is_file():
        group = json.loads((folder / "zarr.json").read_text())
        ome = group["attributes"]["ome"]
        version = ome["version"]
        ms = ome["multiscales"][0]
        zarr_format = 3
    else:
        ms = json.loads((folder / ".zattrs").read_text())["multiscales"][0]
        version = ms["version"]
        zarr_format = 2
    ds = ms["datasets"][0]
    if "axes" in ms:
        axes = ms["axes"]
    else:  # 0.6: the axes of the coordinate system the dataset maps into
        out_name = ds["coordinateTransformations"][0]["output"]["name"]
        axes = next(cs for cs in ms["coordinateSystems"] if cs["name"] == out_name)["axes"]
    arr_dir = folder / ds["path"]
    if zarr_format == 3:
        am = json.loads((arr_dir / "zarr.json").read_text())
        zdtype = am["data_type"]
        dtype = np.dtype(zdtype).name
        chunks = am["chunk_grid"]["configuration"]["chunk_shape"]
        codecs = []
        for c in am["codecs"]:
            if c["name"] == "sharding_indexed":
                inner = ",".join(x["name"] for x in c["configuration"]["codecs"])
                codecs.append(f"sharding_indexed({inner})")
            else:
                codecs.append(c["name"])
    else:
        am = json.loads((arr_dir / ".zarray").read_text())
        zdtype = am["dtype"]
        dtype = np.dtype(zdtype).name
        chunks = am["chunks"]
        codecs = [am["compressor"]["id"]] if am["compressor"] else []
    return {"version": version, "zarr_format": zarr_format, "ms": ms, "axes": axes, "dataset": ds,
            "shape": am["shape"], "dtype": dtype, "zarr_dtype": zdtype, "chunks": chunks, "codecs": codecs}


def flatten(transforms: list) -> list:
    out = []
    for t in transforms:
        if t.get("type") == "sequence":
            out += flatten(t["transformations"])
        else:
            out.append(t)
    return out


def apply(transforms: list, scale: np.ndarray, translation: np.ndarray) -> None:
    """coordinate = scale * index + translation, transformed in place by each scale / translation in turn."""
    for t in flatten(transforms):
        kind = t.get("type")
        if kind == "scale":
            s = np.asarray(t["scale"], dtype=np.float64)
            scale *= s
            translation *= s
        elif kind == "translation":
            translation += np.asarray(t["translation"], dtype=np.float64)
        elif kind == "identity":
            pass
        else:
            raise Refused(f"coordinate transformation of type {kind!r}: only scale and translation are supported")


def spec_reading(meta: dict) -> tuple[dict, list[str]]:
    """What the specification gives (see the module docstring); raises Refused with the reason."""
    axes, shape = meta["axes"], meta["shape"]
    n = len(axes)
    if n != len(shape):
        raise Refused("the axes do not match the array's dimensions")
    scale, translation = np.ones(n), np.zeros(n)
    apply(meta["dataset"].get("coordinateTransformations", []), scale, translation)
    if meta["version"] in ("0.4", "0.5"):
        apply(meta["ms"].get("coordinateTransformations", []), scale, translation)
    warns = []
    space = [i for i, a in enumerate(axes) if a.get("type") == "space"]
    time = [i for i, a in enumerate(axes) if a.get("type") == "time"]
    for i, a in enumerate(axes):
        if a.get("type") == "channel" and shape[i] != 1:
            raise Refused(f"{shape[i]} channels: only one channel is supported")
        if a.get("type") not in ("space", "time", "channel"):
            raise Refused(f"axis {a.get('name')!r} of type {a.get('type')!r}")
    if len(space) != 3 or len(time) > 1:
        raise Refused(f"{len(space)} space axes and {len(time)} time axes: three space axes are needed")
    names = [axes[i]["name"] for i in space]
    if sorted(names) != ["x", "y", "z"]:
        raise Refused(f"space axis names {names}: the axis names must be x, y and z")
    units = {}
    for i in space:
        unit = axes[i].get("unit")
        if unit is not None and unit not in MM_PER_UNIT:
            raise Refused(f"space axis {axes[i]['name']!r} has unit {unit!r}, not a length unit")
        units[axes[i]["name"]] = unit
    orient = {axes[i]["name"]: (axes[i].get("orientation") or {}).get("value") for i in space}
    lps_ok = all(axes[i].get("orientation", {}).get("type") == "anatomical" and orient[axes[i]["name"]]
                 in LPS_OF_ORIENTATION for i in space)
    if lps_ok:
        direction = {name: LPS_OF_ORIENTATION[o] for name, o in orient.items()}
        if abs(np.linalg.det(np.array([direction[k] for k in "xyz"]))) != 1.0:
            raise Refused(f"orientations {orient} do not span three dimensions")
        direction_from = "orientation"
    else:
        direction = dict(LPS_OF_NAME)
        direction_from = "name"
        if any(o is not None for o in orient.values()):
            warns.append(f"orientation {orient} not all LPS-compatible: the axes are taken by name")
    spec_axes = {}
    m = np.eye(4)
    m_ngff = np.eye(4)
    shift = [Fraction(0)] * 3
    for col, i in enumerate(reversed(space)):  # i, j, k: the fastest space axis first
        name = axes[i]["name"]
        mm = Fraction(MM_PER_UNIT[units[name]]) if units[name] else Fraction(1)
        d = direction[name]
        for r in range(3):
            m[r, col] = float(Fraction(d[r]) * Fraction(scale[i]) * mm)
            shift[r] += Fraction(d[r]) * Fraction(translation[i]) * mm
        m_ngff[:3, col] = m[:3, col]
        m_ngff["xyz".index(name), 3] = float(Fraction(translation[i]) * mm)
        spec_axes[name] = {"scale": float(scale[i]), "translation": float(translation[i]), "unit": units[name],
                           "mm_per_unit": float(mm), "orientation": orient[name], "lps_direction": floats(d)}
    m[:3, 3] = [float(v) for v in shift]
    t = time[0] if time else None
    return {
        "axes": {k: spec_axes[k] for k in "xyz"},
        "time": None if t is None else {"name": axes[t]["name"], "scale": float(scale[t]),
                                        "translation": float(translation[t]), "unit": axes[t].get("unit")},
        "direction_from": direction_from,
        "lps_from_index_mm": [floats(r) for r in m],
        "lps_from_index_mm_ngff_zarr": [floats(r) for r in m_ngff],
        "translations_agree": bool(np.array_equal(m[:3, 3], m_ngff[:3, 3])),
    }, warns


def frames_of(arr: np.ndarray, axes: list) -> list[np.ndarray]:
    """Channel 0 of each t frame, the space axes in storage order (C order = i fastest)."""
    types = [a.get("type") for a in axes]
    if "channel" in types:
        arr = np.take(arr, 0, axis=types.index("channel"))
        types.remove("channel")
    if "time" in types:
        t = types.index("time")
        return [np.take(arr, n, axis=t) for n in range(arr.shape[t])]
    return [arr]


def values_entry(frame: np.ndarray) -> dict:
    f64 = np.ascontiguousarray(frame, dtype="<f8")
    return {
        "sha256": sha(f64.tobytes()),
        "sha256_f32": sha(np.ascontiguousarray(f64.astype("<f4")).tobytes()),
        "sum": math.fsum(f64.ravel().tolist()),
        "min": float(f64.min()),
        "max": float(f64.max()),
    }


def ngff_zarr_reading(folder: Path, meta: dict) -> tuple[list | None, str]:
    """ngff_image_to_itk_image of the level-0 image for each frame (channel 0): [itkwasm Image, ...], and what
    happened."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            image = nz.from_ngff_zarr(str(folder)).images[0]
            dims = image.dims
            t_count = image.data.shape[dims.index("t")] if "t" in dims else 1
            out = []
            for n in range(t_count):
                w = nz.ngff_image_to_itk_image(image, t_index=n if "t" in dims else None,
                                               c_index=0 if "c" in dims else None)
                np.asarray(w.data)
                out.append(w)
    except Exception as exc:  # noqa: BLE001 - record whatever ngff-zarr says
        return None, f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
    return out, f"dims {list(dims)}"


def itk_matrix(w, meta: dict, spec: dict) -> np.ndarray:
    """ngff-zarr's ITK geometry as a matrix over (i, j, k) in mm: each ITK axis' column moved to the array axis of
    its name, lengths times mm_per_unit; the multiscale-level scale / translation (0.4 / 0.5) put on top, since
    ngff-zarr leaves them out."""
    axes = [a for a in meta["axes"] if a.get("type") == "space"]
    extra_s, extra_t = np.ones(len(meta["axes"])), np.zeros(len(meta["axes"]))
    if meta["version"] in ("0.4", "0.5"):
        apply(meta["ms"].get("coordinateTransformations", []), extra_s, extra_t)
    by_name = {a["name"]: i for i, a in enumerate(meta["axes"])}
    d = np.asarray(w.direction, dtype=np.float64).reshape(3, 3)
    m = np.eye(4)
    for col, a in enumerate(reversed(axes)):
        name = a["name"]
        c = "xyz".index(name)
        mm = spec["axes"][name]["mm_per_unit"]
        k = by_name[name]
        m[:3, col] = d[:, c] * w.spacing[c] * extra_s[k] * mm
        m[c, 3] = (w.origin[c] * extra_s[k] + extra_t[k]) * mm
    return m


def itk_values_agree(images: list, frames: list[np.ndarray], meta: dict) -> bool:
    """Does ngff-zarr's buffer, read as ITK reads one (x fastest over `size`), hold zarr-python's value at each
    (x, y, z)?"""
    names = [a["name"] for a in meta["axes"] if a.get("type") == "space"]
    for w, frame in zip(images, frames):
        zyx = np.transpose(frame, [names.index(n) for n in "zyx"])
        flat = np.asarray(w.data).ravel()
        if list(w.size) != [zyx.shape[2], zyx.shape[1], zyx.shape[0]] or flat.size != zyx.size:
            return False
        if not np.array_equal(flat.astype(np.float64), zyx.ravel().astype(np.float64)):
            return False
    return True


def describe(folder: Path, refuse: str | None = None, warn: str | None = None, note: str | None = None) -> dict:
    meta = read_metadata(folder)
    entry = {
        "name": folder.name.removesuffix(".ome.zarr"),
        "version": meta["version"],
        "zarr_format": meta["zarr_format"],
        "dtype": meta["dtype"],
        "zarr_dtype": meta["zarr_dtype"],
        "array_axes": [{"name": a["name"], "type": a.get("type"), "unit": a.get("unit"),
                        "orientation": (a.get("orientation") or {}).get("value")} for a in meta["axes"]],
        "shape": meta["shape"],
        "chunks": meta["chunks"],
        "codecs": meta["codecs"],
        "level0_path": meta["dataset"]["path"],
        "frames": next((meta["shape"][i] for i, a in enumerate(meta["axes"]) if a.get("type") == "time"), None),
    }
    refused, warns = None, []
    try:
        spec, warns = spec_reading(meta)
    except Refused as exc:
        spec, refused = None, str(exc)
    frames = None
    if spec is not None:
        try:
            data = zarr.open_array(LocalStore(folder / meta["dataset"]["path"], read_only=True), mode="r")[...]
            frames = frames_of(np.asarray(data), meta["axes"])
        except Exception as exc:  # noqa: BLE001 - a chunk zarr-python cannot decode
            spec, refused = None, f"a chunk cannot be decoded: {type(exc).__name__}: {exc}"
    images, said = ngff_zarr_reading(folder, meta)
    itk_entry, agree = None, None
    if images is not None and len(images[0].size) == 3:
        w = images[0]
        itk_entry = {"size": [int(s) for s in w.size], "origin": floats(w.origin), "spacing": floats(w.spacing),
                     "direction": [floats(r) for r in np.asarray(w.direction).reshape(3, 3)]}
        if spec is not None:
            got = itk_matrix(w, meta, spec)
            np.testing.assert_allclose(got, np.asarray(spec["lps_from_index_mm_ngff_zarr"]), rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(got[:3, :3], np.asarray(spec["lps_from_index_mm"])[:3, :3], rtol=1e-12,
                                       atol=1e-12)
            agree = itk_values_agree(images, frames, meta)
    entry["spec"] = spec
    entry["itk"] = itk_entry
    entry["itk_values_agree"] = agree
    entry["values"] = None if frames is None else [values_entry(f) for f in frames]
    entry["refuse"] = refuse
    entry["warn"] = warn
    entry["ngff_zarr"] = said
    entry["note"] = note
    entry["_refused"] = refused
    entry["_warns"] = warns
    return entry


# ---------------------------------------------------------------------------------------------------- driver

# name -> (refuse, warn, what ngff-zarr does, what the file exercises)
FIXTURES = {
    "v04_i16": (None, None, "reads it; ITK geometry as written, identity direction",
                "0.4 / Zarr v2, int16, zstd, 8 chunks with partial edges, nested dataset path scale0/image, LPS "
                "orientations (as ngff-zarr writes them for an identity direction)"),
    "v05_u16_oriented": (None, None, "reads it; direction from the orientations, origin = the translations by "
                         "axis name (not rotated by the orientations)",
                         "0.5 / Zarr v3, uint16, RFC-4 orientations of a signed permutation, chunks (2, 3, 4)"),
    "v06_f32_ras": (None, None, "reads it; direction diag(-1, -1, 1), origin = the translations by axis name",
                    "0.6, float32, a sequence (scale, translation) in coordinateTransformations with input / "
                    "output, RAS-like orientations"),
    "v04_blosc_u8_levels": (None, None, "reads it (level 0)",
                            "0.4, uint8, Blosc lz4 + shuffle, two levels: the image is the first dataset"),
    "v05_sharded_f64": (None, None, "reads it",
                        "0.5, float64 not exact in float32, sharding_indexed (2^3 inner chunks in 4^3 shards, "
                        "partial edge shards, crc32c index at the end)"),
    "v05_time_i16": (None, None, "reads it; one ITK image per frame (t_index)",
                     "0.5, (t, z, y, x), 3 frames, units second and millimeter, no orientation"),
    "v05_channel1": (None, None, "reads it (c_index 0)", "0.5, (c, z, y, x) with one channel, no orientation"),
    "v04_um_bigendian_i32": (None, None, "reads it; ignores the multiscale-level scale (spacing and origin are "
                             "the dataset's alone) and does not convert micrometres",
                             "0.4, big-endian int32, no compressor, dimension_separator '.', unit micrometer, a "
                             "multiscale-level scale after the dataset's"),
    "v05_xyz_order_fill": (None, None, "geometry by axis name is right, but it hands ITK the buffer in the "
                           "array's (x, y, z) order as if it were (z, y, x): the voxels are scrambled",
                           "0.5, int8, axes stored (x, y, z), gzip, fill_value 7 with one chunk not written"),
    "v05_dorsal": (None, "orientation", "reads it; identity direction (silently: dorsal-to-ventral is not "
                   "LPS-compatible, so no orientation is used, x's left-to-right neither)",
                   "0.5, int16, orientations x left-to-right, y dorsal-to-ventral, z inferior-to-superior"),
    "bad_two_channels": ("channel", None, "reads it: without c_index a 2-component VariableLengthVector image, "
                         "with c_index 0 (the itk entry) channel 0",
                         "0.5, (c, z, y, x) with 2 channels"),
    "bad_rotation_06": ("rotation", None, "reads it, ignoring the rotation in the sequence",
                        "0.6 sequence scale, rotation (30 degrees about z), translation"),
    "bad_unit": ("unit", None, "reads it; units are not looked at", "0.5, unit 'second' on the x (space) axis"),
    "bad_axis_names": ("axis names", None, "reads the array, but its ITK conversion finds no x, y or z (and "
                       "takes the axis named c for channels): a 0-dimensional image of 7-component pixels",
                       "0.5, space axes named a, b, c without orientation"),
    "bad_truncated_chunk": ("chunk", None, "reads the metadata; computing the data fails",
                            "0.5, int16, zstd, chunk c/0/0/0 cut to half its bytes"),
}


def make(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    written = {
        "v04_i16": make_v04_i16(out),
        "v05_u16_oriented": make_v05_u16_oriented(out),
        "v06_f32_ras": make_v06_f32_ras(out),
        "v04_blosc_u8_levels": make_v04_blosc_u8_levels(out),
        "v05_sharded_f64": make_v05_sharded_f64(out),
        "v05_time_i16": make_v05_time_i16(out),
        "v05_channel1": make_v05_channel1(out),
        "v05_dorsal": make_v05_dorsal(out),
        "v04_um_bigendian_i32": make_v04_um_bigendian_i32(out),
        "v05_xyz_order_fill": make_v05_xyz_order_fill(out),
    }
    make_bad(out)

    reference = {
        "readers": {"ngff-zarr": nz.__version__, "zarr": zarr.__version__, "numcodecs": numcodecs.__version__,
                    "itk": itk.Version.GetITKVersion(), "numpy": np.__version__},
        "files": [],
    }
    for name, (refuse, warn, said, note) in FIXTURES.items():
        e = describe(out / f"{name}.ome.zarr", refuse, warn, note)
        refused, warns = e.pop("_refused"), e.pop("_warns")
        # The script's own reading refuses exactly the bad files, with the keyword, and warns for v05_dorsal.
        assert (refused is None) == (refuse is None), (name, refused)
        assert refuse is None or refuse in refused, (name, refused)
        assert (warn is None) == (not warns), (name, warns)
        assert warn is None or all(warn in w for w in warns), (name, warns)
        e["ngff_zarr"] = f"{said}; {e['ngff_zarr']}" if said else e["ngff_zarr"]
        reference["files"].append(e)
    by = {e["name"]: e for e in reference["files"]}

    # The values are the arrays written (with the fill values), and ngff-zarr reads them where said.
    for name, arr in written.items():
        e = by[name]
        meta_axes = [{"type": a["type"]} for a in e["array_axes"]]
        frames = frames_of(arr, meta_axes)
        assert [values_entry(f) for f in frames] == e["values"], name
        assert e["itk"] is not None, name
        assert e["itk_values_agree"] is (name != "v05_xyz_order_fill"), name
    for name in ("v04_i16", "v05_u16_oriented", "v06_f32_ras", "v04_blosc_u8_levels", "v05_sharded_f64",
                 "v05_dorsal", "v04_um_bigendian_i32", "v05_xyz_order_fill", "v05_channel1", "v05_time_i16"):
        s = by[name]["spec"]
        assert s["translations_agree"] is (name not in ("v05_u16_oriented", "v06_f32_ras")), name
    # v04_um_bigendian_i32 is v04_i16's geometry in micrometres.
    np.testing.assert_allclose(by["v04_um_bigendian_i32"]["spec"]["lps_from_index_mm"],
                               by["v04_i16"]["spec"]["lps_from_index_mm"], rtol=1e-13, atol=1e-12)
    assert by["v04_um_bigendian_i32"]["itk"]["spacing"] == [700.0, 2600.0, 1250.0]
    assert by["v05_dorsal"]["itk"]["direction"] == [floats(r) for r in np.eye(3)]
    assert by["v05_u16_oriented"]["itk"]["direction"] == [[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    assert by["v06_f32_ras"]["itk"]["direction"] == [floats(r) for r in np.diag([-1.0, -1.0, 1.0])]
    assert by["bad_rotation_06"]["itk"] == by["v06_f32_ras"]["itk"]  # the rotation is ignored

    (out / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    total = 0
    for d in sorted(out.iterdir()):
        files = [p for p in d.rglob("*") if p.is_file()] if d.is_dir() else [d]
        size = sum(p.stat().st_size for p in files)
        total += size
        print(f"{d.name}: {len(files)} files, {size} bytes")
    print(f"total: {total} bytes")


def check(paths: list[str]) -> None:
    out = []
    for p in paths:
        e = describe(Path(p))
        e["refused"] = e.pop("_refused")
        e["warnings"] = e.pop("_warns")
        out.append(e)
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=OUT, help="where the fixtures go (default tests/data/ngff)")
    ap.add_argument("--check", nargs="+", metavar="DIR",
                    help="print what the specification and ngff-zarr give for each OME-Zarr folder; write nothing")
    args = ap.parse_args()
    if args.check:
        check(args.check)
    else:
        make(args.out)


if __name__ == "__main__":
    main()
