#!/usr/bin/env python3
"""MINC1 and MINC2 fixtures, and what nibabel and SimpleITK read from each: tests/data/minc/.

MINC2 is HDF5: `/minc-2.0/dimensions/{xspace,yspace,zspace,time}` carry `start`, `step`, `direction_cosines`
(and `spacing`, `length`, ...); `/minc-2.0/image/0/image` holds the samples, its `dimorder` attribute names the
dimensions slowest first and `valid_range` the stored range; `image-min` / `image-max` beside it are scalars or
arrays over a prefix of the image's dimensions (their own `dimorder`). MINC1 is a netCDF classic file with the same
names as netCDF dimensions and variables (`image` has `signtype`, `valid_range`; `image-min` / `image-max` are
variables over a prefix of `image`'s dimensions; netCDF's integers are signed, and `signtype` b"unsigned" or
b"signed__" says how MINC reads them; without it libminc reads bytes as unsigned and the rest as signed). World coordinates are RAS mm. The world position of the voxel at index n (along each spatial
dimension d) is sum_d cos_d * (start_d + n_d * step_d); integer samples are real =
(clip(stored, vmin, vmax) - vmin) * (imax - imin) / (vmax - vmin) + imin with imin / imax of the voxel's slice;
float samples are not scaled. This is what nibabel 5.4.2 (`nibabel/minc1.py`, `minc2.py`) does.

The files:

- copied byte for byte from nibabel 5.4.2's `nibabel/tests/data/` (MIT, nibabel's licence): minc1_1_scale.mnc,
  minc1_4d.mnc, minc1-no-att.mnc, tiny.mnc (MINC1, netCDF CDF-1, big-endian samples), minc2_1_scale.mnc,
  minc2_4d.mnc, minc2-no-att.mnc, minc2-4d-d.mnc, minc2_baddim.mnc, small.mnc (MINC2; small.mnc is the MNI ICBM152
  2009a symmetric template resampled by mincresample, see its HDF5 `history`). Their quirks are in each entry's
  `note`: minc2_baddim's xspace has `spacing` b"xspace" (nibabel warns and assumes regular) and `length` 642
  against the data's 10, which libminc refuses; the *-no-att files have no start / step / direction_cosines
  (nibabel: 0, 1 and the axis) and no valid_range (nibabel: the type's range), with scalar image-min / image-max;
  minc2-4d-d is float64 with dimorder time,xspace,yspace,zspace (zspace fastest), the *_4d files have time
  slowest and image-min / image-max over (time, zspace). minc2_1_scale / minc2_4d store the image chunked with
  gzip; SimpleITK's files are contiguous.
- written by SimpleITK 2.5.7 (libminc 2.4.06, `sitk.WriteImage(img, "x.mnc")`): oblique_{u8,i16,u16,f32,f64}.mnc,
  5 x 4 x 3 voxels (x fastest) with spacing (0.7, 1.3, 2.5), direction rotation(0.3, -0.2, 0.5) (about all three
  axes, fixture_grids.py) and origin (-12.5, 30.25, 7.0); values are a ramp with a different step along each axis
  plus a small non-linear term, covering part of each type's range (negatives for i16 / f32 / f64, f64 values
  float32 does not hold). What SimpleITK writes: the image in its own type (u16 stays uint16, nothing is
  rescaled), contiguous, dimorder "zspace,yspace,xspace"; valid_range = [min, max] of the data (for the float
  types too), image-min / image-max scalars equal to the same min and max (so the scaling is the identity);
  the dimensions are scalar float64 datasets with start = cos_d . origin (the ITK origin projected on each
  cosine), step = spacing, direction_cosines = the columns of the ITK direction, length (int32), spacing
  b"regular__", alignment b"centre", width 1.0; the root group /minc-2.0 has attributes ident, minc_version
  b"2.4.06" and class b"real___". SimpleITK reads them back to the same type.
- made by this script with h5py (3.16, HDF5 2.0.0) from one of those (the HDF5 objects are edited in place, with
  libminc's null-terminated fixed-length string attributes), each read by both nibabel and SimpleITK:
  - slice_scaled_i16.mnc: oblique_i16 with its samples replaced by an int16 ramp over most of the type's range,
    valid_range [-32768, 32767] and image-min / image-max arrays over zspace (dimorder "zspace") of non-integer,
    different values per slice;
  - permuted_u8.mnc: oblique_u8 stored with dimorder "xspace,zspace,yspace" (the same real-world volume, the array
    transposed), valid_range [2, 250] (not the type's range; no sample lies outside it) and image-min /
    image-max over xspace (dimorder "xspace");
  - negative_step_i16.mnc: oblique_i16 whose yspace step is -1.3 and start start + 3 * 1.3 (the same voxel centres,
    the cosines unchanged), the samples flipped along yspace so that it is the same real-world volume.
- made with scipy.io.netcdf_file (version 1, CDF-1) after the layout of minc1_1_scale.mnc (mincconvert's):
  oblique_minc1_i16.mnc,
  the oblique grid, signed int16 (big-endian, as netCDF stores it), valid_range [-32768, 32767] and image-min /
  image-max over zspace; oblique_minc1_i16.mnc.gz is its gzip (mtime 0, no name), which nibabel reads to the same
  data.

SimpleITK (ITK's MINCImageIO over libminc) reads MINC2 only (the netCDF files are refused) and gives libminc's
"apparent" order: x fastest whatever the dimorder, every step positive (a negative step is turned into a flipped
axis), time as vector components; integer files whose scaling is not the identity are read as 32-bit float. It
takes MINC's world coordinates as ITK physical coordinates without any RAS/LPS flip, so its origin and direction
are nibabel's RAS numbers.

reference.json: {"readers": {...}, "files": [entry, ...]}, one entry per file, floats as Python's repr
(round-trip exact). From nibabel: `class` (Minc1Image / Minc2Image), `format` (MINC1 / MINC2, by magic; "MINC1+gzip"),
`shape` (file order, slowest first), `dimorder` (the image's dimension names in that order), `dtype` (the on-disk
sample type as numpy writes it, e.g. ">i2", "<u2", "|u1") and `dtype_name` ("int16"), `frames` (the length of
`time`, 1 without), `affine` (nibabel's 4 x 4 RAS affine, its columns following the spatial dimensions in file
order, time left out), `frame_shape` (the spatial shape, file order); for frame 0 (index 0 along `time`, wherever
it sits; the whole array without one) of the real values (`get_fdata()`, float64): `f32_sha256` (sha256 of the
values as little-endian float32, C order of the spatial axes in file order), `min`, `max`, `sum` (`math.fsum`,
the correctly rounded sum) and `first` (the first 8 values in that order); `frame_sums` (the `math.fsum` of
each frame, in time order; one number without time) and `all_f32_sha256` (all the real values, time included,
as little-endian float32 in file order: minc2-4d-d's frame 0 is all zeros, frame t holds t). `hdf5` (MINC2 only):
the superblock version and the image's storage layout and filters. `simpleitk` (null where SimpleITK refuses the
file): `size`, `origin`, `spacing`, `direction` (row-major, as returned), `pixel_type`, `components` and
`f32_sha256` of `GetArrayFromImage` as little-endian float32 in its (k, j, i) C order, for a vector image of
component 0 (frame 0); `max_abs_diff_vs_nibabel`: each SimpleITK voxel is mapped to world by SimpleITK's geometry
and back to a nibabel voxel by nibabel's affine (it must land on one) and its value compared with nibabel's frame 0
(null when the voxels do not correspond; a float32 reading differs by float32's rounding). `source` and `note` say
where each file comes from and what is odd about it.

Determinism: a rerun writes the same bytes. reference.json and the netCDF files are plain; the copies are
nibabel's bytes. SimpleITK's HDF5 files carry object times (in every version-2 object header) and libminc's `ident`
attribute ("$LOGNAME:host:time:pid:counter", in a fractal heap block), whose length moves the HDF5 layout; the
script pads $LOGNAME while SimpleITK writes so that the ident is 64 bytes long, then zeroes the times, overwrites
the ident with a placeholder of the same length ("warpbench:minc_fixtures.py:000...") and recomputes the lookup3
checksums HDF5 keeps over those blocks (only blocks whose checksum verified are touched). A host name over about 35
characters defeats the padding: the bytes then differ, the reading does not. The .gz has mtime 0 and no name.

`--check FILE...` writes nothing: it prints, as JSON, the same reading (nibabel and SimpleITK) of each FILE, e.g.
one warpbench wrote.

Usage, from the repository root (the `.ci/run` venv: nibabel 5.4.2, SimpleITK 2.5.7, h5py, numpy, scipy):

    target/ci-python-venv/bin/python data-scripts/minc_fixtures.py
    target/ci-python-venv/bin/python data-scripts/minc_fixtures.py --check out.mnc
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import math
import os
import shutil
import struct
import sys
import warnings
from pathlib import Path

import h5py
import nibabel as nib
import numpy as np
import scipy
import SimpleITK as sitk
from fixture_grids import rotation
from scipy.io import netcdf_file

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "minc"
NIB_DATA = Path(nib.__file__).resolve().parent / "tests" / "data"

SIZE = (5, 4, 3)  # ITK order, x fastest
SPACING = (0.7, 1.3, 2.5)
ORIGIN = (-12.5, 30.25, 7.0)
DIRECTION = rotation(0.3, -0.2, 0.5)
IDENT_LEN = 64  # the length libminc's ident attribute is brought to (see write_sitk)

NIBABEL_FILES = {
    "minc1_1_scale.mnc": "MINC1 (mincconvert of minc2_1_scale): uint8, scalar image-min/image-max.",
    "minc1_4d.mnc": "MINC1: uint8, dims time,zspace,yspace,xspace (2 frames), image-min/image-max over (time, zspace).",
    "minc1-no-att.mnc": "MINC1 without start/step/direction_cosines (nibabel: start 0, step 1, the axis as cosine) "
    "and without valid_range (nibabel: the type's range); scalar image-min/image-max (0.2078431, 0.7490196; "
    "their _FillValue attributes are not used).",
    "tiny.mnc": "MINC1: uint8 20x20x10, image-min/image-max over zspace, valid_range [0, 255].",
    "minc2_1_scale.mnc": "MINC2: uint8, scalar image-min/image-max, image chunked with gzip, dimensions int32.",
    "minc2_4d.mnc": "MINC2: uint8, dimorder time,zspace,yspace,xspace (2 frames), image-min/image-max over "
    "(time, zspace), chunked with gzip; SimpleITK reads time as 2 vector components.",
    "minc2-no-att.mnc": "MINC2 without start/step/direction_cosines (nibabel: 0, 1, the axis) and without "
    "valid_range; scalar image-min/image-max whose dimorder attributes (zspace / yspace) do not fit their "
    "scalar shape (nibabel keeps as many names as the dataset has dimensions, none).",
    "minc2-4d-d.mnc": "MINC2: float64 (not scaled), dimorder time,xspace,yspace,zspace (time slowest, zspace "
    "fastest), 5 frames; SimpleITK reads it as 5 vector components in x-fastest order.",
    "minc2_baddim.mnc": "MINC2 whose xspace has spacing b'xspace' (nibabel warns and assumes regular) and length "
    "642 while the data has 10 along it; libminc (SimpleITK) refuses to open it.",
    "small.mnc": "MINC2: int16, image-min/image-max over zspace, valid_range [-32768, 32767]; the MNI ICBM152 "
    "2009a template resampled to 29x28x18 (7, 8, 9 mm).",
}


# ---------------------------------------------------------------------------------------------------- reading


def sha_f32(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype="<f4").tobytes()).hexdigest()


def floats(a) -> list:
    return [float(x) for x in np.asarray(a, dtype=np.float64).ravel()]


def magic(path: Path) -> str:
    raw = path.read_bytes()[:4]
    if raw[:2] == b"\x1f\x8b":
        raw = gzip.decompress(path.read_bytes())[:4]
        return {b"CDF\x01": "MINC1+gzip", b"CDF\x02": "MINC1+gzip"}.get(raw, "unknown+gzip")
    if raw in (b"CDF\x01", b"CDF\x02"):
        return "MINC1"
    if raw == b"\x89HDF":
        return "MINC2"
    return "unknown"


def hdf5_info(path: Path) -> dict | None:
    if magic(path) != "MINC2":
        return None
    with h5py.File(path, "r") as f:
        im = f["minc-2.0/image/0/image"]
        plist = im.id.get_create_plist()
        layout = {h5py.h5d.COMPACT: "compact", h5py.h5d.CONTIGUOUS: "contiguous", h5py.h5d.CHUNKED: "chunked"}
        filters = []
        for i in range(plist.get_nfilters()):
            code = plist.get_filter(i)[0]
            filters.append({h5py.h5z.FILTER_DEFLATE: "deflate", h5py.h5z.FILTER_SHUFFLE: "shuffle"}.get(code, code))
        return {
            "superblock": f.id.get_create_plist().get_version()[0],
            "image_layout": layout[plist.get_layout()],
            "image_chunks": list(im.chunks) if im.chunks else None,
            "image_filters": filters,
        }


def nibabel_frames(img) -> tuple[np.ndarray, np.ndarray, list[str], list[float]]:
    """The real values, frame 0 of them, the dimension names and the sum of each frame."""
    dims = list(img.dataobj.minc_file._dim_names)
    data = img.get_fdata()
    frame, sums = data, [math.fsum(data.ravel().tolist())]
    if "time" in dims:
        t = dims.index("time")
        frame = np.take(data, 0, axis=t)
        sums = [math.fsum(np.take(data, n, axis=t).ravel().tolist()) for n in range(data.shape[t])]
    return data, frame, dims, sums


def describe_nibabel(path: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        img = nib.load(str(path))
        data, frame, dims, sums = nibabel_frames(img)
    dtype = img.get_data_dtype()
    return (
        {
            "class": type(img).__name__,
            "shape": [int(n) for n in img.shape],
            "dimorder": dims,
            "dtype": dtype.str,
            "dtype_name": dtype.name,
            "frames": len(sums),
            "affine": [floats(row) for row in img.affine],
            "frame_shape": [int(n) for n in frame.shape],
            "f32_sha256": sha_f32(frame),
            "min": float(frame.min()),
            "max": float(frame.max()),
            "sum": math.fsum(frame.ravel().tolist()),
            "first": floats(frame.ravel()[:8]),
            "frame_sums": sums,
            "all_f32_sha256": sha_f32(data),
        },
        frame,
        np.asarray(img.affine, dtype=np.float64),
    )


def compare(sitk_img, arr_kji: np.ndarray, nib_frame: np.ndarray, nib_affine: np.ndarray) -> float | None:
    """The largest |SimpleITK - nibabel| over SimpleITK's voxels matched by world position; None if they do not
    correspond voxel for voxel."""
    k, j, i = np.indices(arr_kji.shape, dtype=np.float64)
    idx = np.stack([i.ravel(), j.ravel(), k.ravel()])
    d = np.asarray(sitk_img.GetDirection(), dtype=np.float64).reshape(3, 3)
    world = d @ (np.asarray(sitk_img.GetSpacing())[:, None] * idx) + np.asarray(sitk_img.GetOrigin())[:, None]
    nib_idx = np.linalg.solve(nib_affine[:3, :3], world - nib_affine[:3, 3:4])
    rounded = np.rint(nib_idx)
    if nib_frame.ndim != 3 or np.abs(nib_idx - rounded).max() > 1e-6:
        return None
    rounded = rounded.astype(int)
    if (rounded < 0).any() or (rounded >= np.asarray(nib_frame.shape)[:, None]).any():
        return None
    if len({tuple(c) for c in rounded.T}) != rounded.shape[1] or rounded.shape[1] != nib_frame.size:
        return None
    theirs = nib_frame[tuple(rounded)]
    return float(np.abs(arr_kji.ravel().astype(np.float64) - theirs).max())


def describe_sitk(path: Path, nib_frame, nib_affine) -> dict | None:
    if path.suffix == ".gz":
        return None
    try:
        img = sitk.ReadImage(str(path))
    except RuntimeError:
        return None
    arr = sitk.GetArrayFromImage(img)
    if img.GetNumberOfComponentsPerPixel() > 1:
        arr = arr[..., 0]
    out = {
        "size": list(img.GetSize()),
        "origin": floats(img.GetOrigin()),
        "spacing": floats(img.GetSpacing()),
        "direction": floats(img.GetDirection()),
        "pixel_type": img.GetPixelIDTypeAsString(),
        "components": img.GetNumberOfComponentsPerPixel(),
        "f32_sha256": sha_f32(arr),
        "max_abs_diff_vs_nibabel": None,
    }
    if nib_frame is not None and img.GetDimension() == 3:
        out["max_abs_diff_vs_nibabel"] = compare(img, arr, nib_frame, nib_affine)
    return out


def describe(path: Path) -> dict:
    entry: dict = {"file": path.name, "format": magic(path)}
    nib_entry, frame, aff = describe_nibabel(path)
    entry.update(nib_entry)
    entry["hdf5"] = hdf5_info(path)
    entry["simpleitk"] = describe_sitk(path, frame, aff)
    return entry


# ---------------------------------------------------------------------------------------------------- writing


def ramp(dtype, base, steps, wiggle) -> np.ndarray:
    """A (z, y, x) array: base + steps . (x, y, z) + wiggle * ((x*y + 2*z*x) % 5); different along each axis."""
    z, y, x = np.indices(SIZE[::-1], dtype=np.float64)
    v = base + steps[0] * x + steps[1] * y + steps[2] * z + wiggle * ((x * y + 2 * z * x) % 5)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        assert info.min <= v.min() and v.max() <= info.max
        v = np.rint(v)
    return v.astype(dtype)


def volumes() -> dict[str, np.ndarray]:
    return {
        "u8": ramp(np.uint8, 3, (7, 29, 53), 1),
        "i16": ramp(np.int16, -20000, (1500, 4100, 13000), 17),
        "u16": ramp(np.uint16, 1000, (1700, 5300, 20000), 13),
        "f32": ramp(np.float32, -1234.5, (12.25, 101.125, 997.0625), 0.375),
        "f64": ramp(np.float64, -3.3, (0.1, -7.7, 1000.01), 1e-9),
    }


def ident_of(path: Path) -> bytes:
    with h5py.File(path, "r") as f:
        return bytes(f["minc-2.0"].attrs["ident"])


def with_fixed_ident(write, written: Path) -> None:
    """Runs `write` (a SimpleITK write whose libminc stamps the MINC 2 file `written` with its ident,
    "$LOGNAME:host:time:pid:counter"), with $LOGNAME padded and the write repeated until the ident is IDENT_LEN bytes
    long, which makes the HDF5 layout independent of the pid."""
    saved = os.environ.get("LOGNAME")
    try:
        for _ in range(4):
            write()
            ident = ident_of(written)
            if len(ident) == IDENT_LEN:
                break
            user = len(ident.split(b":")[0])
            os.environ["LOGNAME"] = "w" * max(0, user + IDENT_LEN - len(ident))
    finally:
        if saved is None:
            os.environ.pop("LOGNAME", None)
        else:
            os.environ["LOGNAME"] = saved


def write_sitk(arr: np.ndarray, path: Path) -> None:
    """sitk.WriteImage, with $LOGNAME padded so that libminc's ident ("$LOGNAME:host:time:pid:counter") is
    IDENT_LEN bytes long (rewritten until it is), which makes the HDF5 layout independent of the pid."""
    img = sitk.GetImageFromArray(arr)
    img.SetSpacing(SPACING)
    img.SetOrigin(ORIGIN)
    img.SetDirection(DIRECTION.flatten().tolist())
    with_fixed_ident(lambda: sitk.WriteImage(img, str(path)), path)


def set_str(obj, name: str, value) -> None:
    """A fixed-length null-terminated string attribute holding exactly `value`'s bytes, as libminc writes them."""
    value = value.encode() if isinstance(value, str) else bytes(value)
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(len(value))
    tid.set_strpad(h5py.h5t.STR_NULLTERM)
    if name in obj.attrs:
        del obj.attrs[name]
    attr = h5py.h5a.create(obj.id, name.encode(), tid, h5py.h5s.create(h5py.h5s.SCALAR))
    attr.write(np.array(value, dtype=f"S{len(value)}"), mtype=tid)


def set_scaling(group, name: str, values, dimorder: str) -> None:
    old = group[name]
    attrs = {k: old.attrs[k] for k in old.attrs}
    del group[name]
    ds = group.create_dataset(name, data=np.asarray(values, dtype=np.float64), track_times=False)
    for k, v in attrs.items():
        set_str(ds, k, v)
    set_str(ds, "dimorder", dimorder)


def make_slice_scaled(src: Path, dst: Path) -> np.ndarray:
    """Returns the real values (z, y, x) the file describes."""
    shutil.copyfile(src, dst)
    stored = ramp(np.int16, -31000, (2700, 5600, 15500), 211)
    imin = np.array([-10.25, 3.5, -100.125])
    imax = np.array([20.75, 1003.5, 50.3])
    with h5py.File(dst, "r+") as f:
        g = f["minc-2.0/image/0"]
        g["image"][...] = stored
        g["image"].attrs["valid_range"] = np.array([-32768.0, 32767.0])
        set_scaling(g, "image-min", imin, "zspace")
        set_scaling(g, "image-max", imax, "zspace")
    slope = (imax - imin) / 65535.0
    return (stored - -32768.0) * slope[:, None, None] + imin[:, None, None]


def make_permuted(src: Path, dst: Path) -> None:
    shutil.copyfile(src, dst)
    with h5py.File(dst, "r+") as f:
        g = f["minc-2.0/image/0"]
        old = g["image"]
        data = old[()]  # (z, y, x)
        attrs = {k: old.attrs[k] for k in old.attrs}
        del g["image"]
        ds = g.create_dataset("image", data=np.ascontiguousarray(data.transpose(2, 0, 1)), track_times=False)
        for k, v in attrs.items():
            if k == "valid_range":
                ds.attrs.create(k, np.array([2.0, 250.0]))
            elif k == "dimorder":
                set_str(ds, k, "xspace,zspace,yspace")
            else:
                set_str(ds, k, v)
        assert data.min() >= 2 and data.max() <= 250
        set_scaling(g, "image-min", [-1.5, 0.0, 2.25, 10.0, -40.125], "xspace")
        set_scaling(g, "image-max", [1.5, 100.0, 3.0, 250.5, 40.0], "xspace")


def make_negative_step(src: Path, dst: Path) -> None:
    shutil.copyfile(src, dst)
    with h5py.File(dst, "r+") as f:
        y = f["minc-2.0/dimensions/yspace"]
        n = f["minc-2.0/image/0/image"].shape[1]
        step = float(y.attrs["step"])
        y.attrs["start"] = float(y.attrs["start"]) + (n - 1) * step
        y.attrs["step"] = -step
        im = f["minc-2.0/image/0/image"]
        im[...] = im[()][:, ::-1, :]


def make_minc1(dst: Path, stored: np.ndarray, imin, imax) -> None:
    starts = DIRECTION.T @ np.asarray(ORIGIN)
    nc = netcdf_file(str(dst), "w", version=1)
    nc.ident = b"warpbench:minc_fixtures.py"
    nc.minc_version = b"2.4.06"
    nc.history = b"data-scripts/minc_fixtures.py\n"
    names = ["zspace", "yspace", "xspace"]
    for name, n in zip(names, stored.shape):
        nc.createDimension(name, n)
    image = nc.createVariable("image", "h", tuple(names))
    image.dimorder = b"zspace,yspace,xspace"
    image.varid = b"MINC standard variable"
    image.vartype = b"group________"
    image.version = b"MINC Version    1.0"
    image.valid_range = np.array([-32768.0, 32767.0])
    image.complete = b"true_"
    image.signtype = b"signed__"
    for name, vals in (("image-min", imin), ("image-max", imax)):
        v = nc.createVariable(name, "d", ("zspace",))
        v.dimorder = b"zspace"
        v.varid = b"MINC standard variable"
        v.vartype = b"var_attribute"
        v.version = b"MINC Version    1.0"
        v[:] = np.asarray(vals, dtype=np.float64)
    comments = {"x": b"X increases from patient left to right", "y": b"Y increases from patient posterior to "
                b"anterior", "z": b"Z increases from patient inferior to superior"}
    for axis, name in enumerate(["xspace", "yspace", "zspace"]):
        v = nc.createVariable(name, "i", ())
        v.data[...] = 0  # scipy leaves a scalar variable's value uninitialised (and its assignValue fails on 0-d)
        v.varid = b"MINC standard variable"
        v.vartype = b"dimension____"
        v.version = b"MINC Version    1.0"
        v.comments = comments[name[0]]
        v.spacing = b"regular__"
        v.alignment = b"centre"
        v.units = b"mm"
        v.start = np.float64(starts[axis])
        v.step = np.float64(SPACING[axis])
        v.direction_cosines = np.ascontiguousarray(DIRECTION[:, axis], dtype=np.float64)
    image[:] = stored
    nc.close()


def gzip_file(src: Path, dst: Path) -> None:
    with open(dst, "wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as gz:
        gz.write(src.read_bytes())


# ---------------------------------------------------------------------------------------------- HDF5 normalisation

_M = 0xFFFFFFFF


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _M


_MIX = ((0, 2, 1, 4), (1, 0, 2, 6), (2, 1, 0, 8), (0, 2, 1, 16), (1, 0, 2, 19), (2, 1, 0, 4))
_FINAL = ((2, 1, 14), (0, 2, 11), (1, 0, 25), (2, 1, 16), (0, 2, 4), (1, 0, 14), (2, 1, 24))


def lookup3(data: bytes) -> int:
    """Bob Jenkins' lookup3 hashlittle with initval 0: HDF5's metadata checksum. v = [a, b, c]."""
    n = len(data)
    v = [(0xDEADBEEF + n) & _M] * 3
    i = 0
    while n > 12:
        for w in range(3):
            v[w] = (v[w] + int.from_bytes(data[i + 4 * w : i + 4 * w + 4], "little")) & _M
        for x, y, z, k in _MIX:  # x -= y; x ^= rot(y, k); y += z
            v[x] = ((v[x] - v[y]) & _M) ^ _rot(v[y], k)
            v[y] = (v[y] + v[z]) & _M
        n -= 12
        i += 12
    if n == 0:
        return v[2]
    tail = data[i : i + n] + bytes(12 - n)
    for w in range(3):
        v[w] = (v[w] + int.from_bytes(tail[4 * w : 4 * w + 4], "little")) & _M
    for x, y, k in _FINAL:  # x ^= y; x -= rot(y, k)
        v[x] = ((v[x] ^ v[y]) - _rot(v[y], k)) & _M
    return v[2]


def _find_all(raw: bytes, sig: bytes):
    p = raw.find(sig)
    while p >= 0:
        yield p
        p = raw.find(sig, p + 1)


def normalise_hdf5(path: Path) -> None:
    """Zero the times of every version-2 object header, replace libminc's ident by a placeholder of the same length
    and recompute the checksums of the blocks that hold them. Only blocks whose stored checksum verifies are
    touched."""
    with h5py.File(path, "r") as f:
        ident = bytes(f["minc-2.0"].attrs["ident"])
    raw = bytearray(path.read_bytes())
    # (start, end of checksummed bytes, checksum offset, zero the checksum while hashing?)
    blocks = []
    for p in _find_all(raw, b"OHDR\x02"):
        flags = raw[p + 5]
        q = p + 6 + (16 if flags & 0x20 else 0) + (4 if flags & 0x10 else 0)
        w = 1 << (flags & 3)
        end = q + w + int.from_bytes(raw[q : q + w], "little")
        if end + 4 <= len(raw) and struct.unpack_from("<I", raw, end)[0] == lookup3(bytes(raw[p:end])):
            blocks.append((p, end, end, False))
            if flags & 0x20:
                raw[p + 6 : p + 22] = bytes(16)
    for p in _find_all(raw, b"FHDB"):
        # fractal heap direct block: signature, version, heap address (8), block offset (w), checksum, data
        for w in range(1, 9):
            cpos = p + 13 + w
            stored = struct.unpack_from("<I", raw, cpos)[0]
            found = False
            for size in (512, 1024, 2048, 4096, 8192, 16384, 32768, 65536):
                if p + size > len(raw):
                    break
                blk = bytearray(raw[p : p + size])
                blk[cpos - p : cpos - p + 4] = bytes(4)
                if lookup3(bytes(blk)) == stored:
                    blocks.append((p, p + size, cpos, True))
                    found = True
                    break
            if found:
                break
    where = raw.find(ident)
    assert where >= 0 and raw.find(ident, where + 1) < 0, f"{path.name}: ident not found once"
    assert any(s <= where and where + len(ident) <= e for s, e, _, _ in blocks), f"{path.name}: ident block"
    raw[where : where + len(ident)] = (b"warpbench:minc_fixtures.py:" + b"0" * len(ident))[: len(ident)]
    for start, end, cpos, zeroed in blocks:
        blk = bytearray(raw[start:end])
        if zeroed:
            blk[cpos - start : cpos - start + 4] = bytes(4)
        struct.pack_into("<I", raw, cpos, lookup3(bytes(blk)))
    path.write_bytes(bytes(raw))


# ---------------------------------------------------------------------------------------------------- driver


def make() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    entries = []

    for name, note in NIBABEL_FILES.items():
        shutil.copyfile(NIB_DATA / name, OUT / name)
        assert (OUT / name).read_bytes() == (NIB_DATA / name).read_bytes()
        entries.append((name, f"nibabel {nib.__version__} nibabel/tests/data/{name} (MIT)", note))

    vols = volumes()
    for kind, arr in vols.items():
        path = OUT / f"oblique_{kind}.mnc"
        write_sitk(arr, path)
        normalise_hdf5(path)
        entries.append((path.name, f"SimpleITK {sitk.Version_VersionString()} WriteImage",
                        f"{arr.dtype.name} on the oblique grid; SimpleITK's valid_range, image-min and image-max "
                        "are the data's min and max (identity scaling)."))

    expected = make_slice_scaled(OUT / "oblique_i16.mnc", OUT / "slice_scaled_i16.mnc")
    make_permuted(OUT / "oblique_u8.mnc", OUT / "permuted_u8.mnc")
    make_negative_step(OUT / "oblique_i16.mnc", OUT / "negative_step_i16.mnc")
    for name in ("slice_scaled_i16.mnc", "permuted_u8.mnc", "negative_step_i16.mnc"):
        normalise_hdf5(OUT / name)
    entries += [
        ("slice_scaled_i16.mnc", "h5py edit of oblique_i16.mnc",
         "int16, valid_range [-32768, 32767], image-min/image-max arrays over zspace (dimorder zspace): "
         "min [-10.25, 3.5, -100.125], max [20.75, 1003.5, 50.3]."),
        ("permuted_u8.mnc", "h5py edit of oblique_u8.mnc",
         "uint8 stored with dimorder xspace,zspace,yspace (the same world volume as oblique_u8, transposed), "
         "valid_range [2, 250], image-min/image-max over xspace: min [-1.5, 0, 2.25, 10, -40.125], "
         "max [1.5, 100, 3, 250.5, 40]."),
        ("negative_step_i16.mnc", "h5py edit of oblique_i16.mnc",
         "oblique_i16 with yspace step -1.3 and start moved to the last voxel centre (cosines unchanged), samples "
         "flipped along yspace: the same world volume; SimpleITK flips it back to positive steps."),
    ]

    mstored = ramp(np.int16, -30500, (2300, 5900, 16000), 401)
    mmin, mmax = [-7.5, 0.125, 1000.0], [12.5, 4095.875, 1000.5]
    make_minc1(OUT / "oblique_minc1_i16.mnc", mstored, mmin, mmax)
    gzip_file(OUT / "oblique_minc1_i16.mnc", OUT / "oblique_minc1_i16.mnc.gz")
    m1note = ("MINC1 (netCDF CDF-1) on the oblique grid, big-endian int16, valid_range [-32768, 32767], "
              f"image-min/image-max over zspace: min {mmin}, max {mmax}.")
    entries += [
        ("oblique_minc1_i16.mnc", f"scipy {scipy.__version__} netcdf_file (version 1)", m1note),
        ("oblique_minc1_i16.mnc.gz", "gzip (mtime 0) of oblique_minc1_i16.mnc", m1note),
    ]

    reference = {
        "readers": {
            "nibabel": nib.__version__,
            "SimpleITK": sitk.Version_VersionString(),
            "h5py": h5py.__version__,
            "numpy": np.__version__,
        },
        "files": [],
    }
    for name, source, note in entries:
        entry = describe(OUT / name)
        entry["source"] = source
        entry["note"] = note
        reference["files"].append(entry)
    by = {e["file"]: e for e in reference["files"]}

    # Checks.
    for kind, arr in vols.items():
        e = by[f"oblique_{kind}.mnc"]
        assert e["f32_sha256"] == sha_f32(arr) and e["shape"] == [3, 4, 5], kind
        np.testing.assert_allclose(np.asarray(e["affine"])[:3, 3], ORIGIN, atol=1e-9)
        s = e["simpleitk"]
        assert s["f32_sha256"] == sha_f32(arr) and s["max_abs_diff_vs_nibabel"] == 0.0, kind
    assert by["slice_scaled_i16.mnc"]["f32_sha256"] == sha_f32(expected)
    assert by["permuted_u8.mnc"]["dimorder"] == ["xspace", "zspace", "yspace"]
    assert by["negative_step_i16.mnc"]["simpleitk"]["f32_sha256"] == sha_f32(vols["i16"])
    for name in ("slice_scaled_i16.mnc", "permuted_u8.mnc", "negative_step_i16.mnc"):
        diff = by[name]["simpleitk"]["max_abs_diff_vs_nibabel"]
        assert diff is not None and diff <= 1e-4 * max(1.0, abs(by[name]["max"]), abs(by[name]["min"])), name
    m1, m1gz = by["oblique_minc1_i16.mnc"], by["oblique_minc1_i16.mnc.gz"]
    assert {k: v for k, v in m1.items() if k not in ("file", "format", "source")} == {
        k: v for k, v in m1gz.items() if k not in ("file", "format", "source")}
    np.testing.assert_allclose(np.asarray(m1["affine"]), np.asarray(by["oblique_i16.mnc"]["affine"]), atol=1e-12)
    refused = sorted(e["file"] for e in reference["files"] if e["simpleitk"] is None)
    assert refused == ["minc1-no-att.mnc", "minc1_1_scale.mnc", "minc1_4d.mnc", "minc2_baddim.mnc",
                       "oblique_minc1_i16.mnc", "oblique_minc1_i16.mnc.gz", "tiny.mnc"], refused

    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    total = 0
    for p in sorted(OUT.iterdir()):
        total += p.stat().st_size
        print(f"{p.name}: {p.stat().st_size} bytes")
    print(f"total: {total} bytes")


def check(paths: list[str]) -> None:
    out = []
    for p in paths:
        path = Path(p)
        entry: dict = {"file": p, "format": magic(path)}
        frame = aff = None
        try:
            nib_entry, frame, aff = describe_nibabel(path)
            entry.update(nib_entry)
        except Exception as exc:  # noqa: BLE001 - report whatever nibabel says
            entry["nibabel_error"] = f"{type(exc).__name__}: {exc}"
        entry["hdf5"] = hdf5_info(path)
        entry["simpleitk"] = describe_sitk(path, frame, aff)
        out.append(entry)
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", nargs="+", metavar="FILE",
                    help="print what nibabel and SimpleITK read from each FILE; write nothing")
    args = ap.parse_args()
    if args.check:
        check(args.check)
    else:
        make()


if __name__ == "__main__":
    main()
