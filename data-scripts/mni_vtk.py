#!/usr/bin/env python3
"""MNI tag point (.tag) and transform (.xfm) files written by VTK, and what VTK and SimpleITK read from each:
tests/data/mni/.

World coordinates are RAS mm throughout. The files (VTK 9.7.1, `vtkmodules.vtkIOMINC`):

- tag files written by `vtkMNITagPointWriter` from double-precision points (VTK writes `%.15g`; without
  `SetComments` it writes `% Volume 1 produced by VTK` and, for two volumes, `% Volume 2 produced by VTK`):
  - pairs.tag: two volumes, 5 points whose coordinates are non-round but exact in float32 (k / 64, negatives
    included), labels with spaces;
  - pairs_ids.tag: two volumes, 4 points with decimal coordinates (not exact in float32), weights, structure ids,
    patient ids and labels (VTK writes all three numbers when any of the arrays is set, 0 / -1 / -1 for
    those not set);
  - pairs_nolabels.tag: two volumes, 4 points (float32-exact), nothing after the coordinates;
  - one_volume.tag: one volume (`Volumes = 1;`), 3 points (float32-exact), labels;
  - comments.tag: two volumes, 3 points (decimal), labels, and `SetComments` text of three lines: VTK prefixes
    each line that does not start with `%` by `% ` and keeps one that does as it is.
- hand_written.tag: written by this script as text in the layout of MNI volume_io's `output_tag_points` (what
  register and tagtoxfm write): header, `Volumes = 2;`, comment lines made by volume_io's `output_comments`
  (`%` directly followed by the text), a blank line, `Points =`, each point on its own line starting with a space
  (`%.15g` coordinates of volume 1 then volume 2, a double-quoted label; one label is empty, `""`), the last one
  followed by `;`.
- transform files written by `vtkMNITransformWriter`:
  - linear.xfm: a general affine (rotation(0.3, -0.2, 0.5) of fixture_grids.py times diag(1.1, 0.9, 1.25), then a
    translation (12.5, -7.25, 3.125));
  - linear_inverted.xfm: linear.xfm with `Invert_Flag = True;` put after `Transform_Type = Linear;` by this
    script. VTK's writer never writes the flag for a linear transform (nor does MNI's volume_io: both write the
    inverse's matrix instead); both readers accept it there and invert the matrix;
  - concatenated.xfm: a vtkGeneralTransform (PostMultiply) of linear.xfm's affine followed by a second affine
    (rotation(-0.1, 0.25, 0.05) times diag(0.95, 1.05, 1.0), translation (-3.5, 2.0, 8.75)); VTK writes them as
    two `Transform_Type = Linear;` blocks, the first applied first;
  - grid.xfm + grid_grid.mnc: a vtkGridTransform over a 6 x 5 x 4 grid (x fastest) of 10 mm spacing with origin
    (-25, -20, -15) (so x in [-25, 25], y in [-20, 20], z in [-15, 15]) and smooth displacements (each
    component under 3 mm, lengths under 3.6 mm); VTK writes the displacement volume beside the .xfm as `<stem>_grid.mnc`, a MINC 1 (netCDF
    CDF-1) file, float64, dimensions zspace, yspace, xspace, vector_dimension (vector_dimension fastest, length
    3), no direction_cosines, start = the origin, step = the spacing;
  - grid_inverted.xfm + grid_inverted_grid.mnc: the same grid under `Invert_Flag = True;` (VTK writes it for an
    inverted vtkGridTransform);
  - tps.xfm: a vtkThinPlateSplineTransform (basis R, 3-D) through 6 landmarks; VTK writes the source points and
    the solved spline coefficients as MNI's `Points` / `Displacements` (n rows of weights, the translation, then
    the 3 x 3 matrix's rows); warpbench refuses this type. VTK's writer only finds 3-D when the first landmark
    with y != 0 also has z != 0 (else it says 2-D and refuses basis R, leaving a file cut after
    `Transform_Type`): the first landmark has both;
- grid_itk.xfm + grid_itk_grid_0.mnc: the same displacements written by SimpleITK (`sitk.WriteTransform` of a
  DisplacementFieldTransform: ITK's MINCTransformIO over libminc 2.4), whose grid volume is MINC 2 (HDF5),
  float64, dimorder zspace,yspace,xspace,vector_dimension. VTK cannot read MINC 2 and SimpleITK cannot read
  MINC 1, so the grid is there in both, each read by the one that can.

reference.json:

    {"readers": {"vtk": ..., "SimpleITK": ...},
     "test_points": [[x, y, z], ...],            # 20 RAS points, the same for every transform
     "tags": [{"file", "source", "volumes", "points": [[[x, y, z], ...] per volume], "labels": [..] | null,
               "weights": [..] | null, "structure_ids": [..] | null, "patient_ids": [..] | null,
               "comments": str | null, "vtk_points_dtype"}],
     "transforms": [{"file", "files", "source", "vtk": READING, "sitk": READING, "grid_volume": {...} | null}]}

READING (vtk): {"error": null | str, "class": the class of `GetTransform()`, "classes": the class of each
`GetNthTransform(i)` in file order, "inverse_flags": each one's `GetInverseFlag()`, "comments", "points":
`TransformPoint` of each test point, "inverse_points": `GetInverse().TransformPoint` (for a grid or spline, VTK's
iterative inverse at the reader's tolerance: vtkMNITransformReader sets InverseTolerance 0.05 on grid transforms,
vtkThinPlateSplineTransform keeps its 0.001), "inverse_tolerance" (those tolerances, null without a grid or
spline); for a grid or spline also "points_tight" and "inverse_points_tight" (the same with InverseTolerance 1e-6
mm and 500 iterations, on copies of the members: `points` of an inverted grid is itself an iterative inverse) and
"tight_error" (VTK's message when an iteration stopped short: for grid.xfm one point ends at 4.2e-6 after 500
iterations; every tight inverse maps back onto its test point within 1e-5 mm, which the script checks). READING (sitk): {"error": null | str, "class"
(`GetName()`), "members" (the classes of a composite's transforms), "points", "inverse_points" (null with
"inverse_error" when `GetInverse()` fails)}. A VTK error is its first message line; a SimpleITK error is the
exception's first line and its `ITK ERROR` / `sitk::ERROR` line; object addresses and the file's directory are
removed from both.
"grid_volume" describes a grid transform's MINC file: format, dimorder, shape, dtype, start, step,
direction_cosines (null when absent) and the values in file order (C order of dimorder). Floats are Python's repr.

What the readers do: VTK's tag reader keeps points in float32 vtkPoints (`vtk_points_dtype`), so decimal
coordinates come back rounded to float32; the float32-exact fixtures read back exactly. VTK's grid transform is
tricubic (vtkMNITransformReader sets cubic interpolation; MNI's volume_io uses a cubic interpolating spline too,
dropping to linear within a voxel of the edge and to zero displacement outside); ITK's DisplacementFieldTransform
interpolates linearly and has no inverse. Outside the grid VTK clamps to the edge values; ITK gives zero
displacement. The test points include two grid nodes (where both give the stored displacement), points near the
edge and two outside.

Determinism: a rerun writes the same bytes. vtkMNITransformWriter stamps `% Creation time: <local time>`: the
script replaces that time by 2000.01.01.00.00.00. vtkMINCImageWriter puts the time and pid in the global `ident`
and `history` attributes: the script rewrites the netCDF header with fixed values (ident
"warpbench:mni_vtk.py:2000.01.01.00.00.00:0:1", history "Sat Jan  1 00:00:00 2000>>>Created by
vtkMINCImageWriter\\n"), shifting the variables' begin offsets; the rest of the file is VTK's bytes. The MINC 2
grid is normalised with minc_fixtures.py's `normalise_hdf5` (object times zeroed, libminc's ident, brought to 64
bytes by padding $LOGNAME while SimpleITK writes, replaced by the placeholder "warpbench:minc_fixtures.py:000...",
checksums recomputed). The tag files and the text of grid_itk.xfm carry no time.

`--check FILE...` writes nothing: it prints, as JSON, the same reading of each .tag (VTK) or .xfm (VTK and
SimpleITK, at the same 20 test points), e.g. a file warpbench wrote.

Usage, from the repository root (the `.ci/run` venv: vtk 9.7.1, SimpleITK 2.5.7, numpy, scipy, h5py):

    target/ci-python-venv/bin/python data-scripts/mni_vtk.py
    target/ci-python-venv/bin/python data-scripts/mni_vtk.py --check out.tag out.xfm
"""

from __future__ import annotations

import argparse
import json
import os
import re
import struct
import sys
from pathlib import Path

import h5py
import numpy as np
import SimpleITK as sitk
from fixture_grids import affine, rotation
from scipy.io import netcdf_file
from vtkmodules.util.numpy_support import numpy_to_vtk
from vtkmodules.vtkCommonCore import (
    vtkDoubleArray,
    vtkIntArray,
    vtkLogger,
    vtkOutputWindow,
    vtkPoints,
    vtkStringArray,
    vtkStringOutputWindow,
    vtkVersion,
)
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonTransforms import vtkGeneralTransform, vtkThinPlateSplineTransform, vtkTransform
from vtkmodules.vtkFiltersHybrid import vtkGridTransform
from vtkmodules.vtkIOMINC import (
    vtkMNITagPointReader,
    vtkMNITagPointWriter,
    vtkMNITransformReader,
    vtkMNITransformWriter,
)

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "mni"

GRID_SIZE = (6, 5, 4)  # x, y, z
GRID_SPACING = 10.0
GRID_ORIGIN = (-25.0, -20.0, -15.0)

LINEAR = affine(rotation(0.3, -0.2, 0.5) @ np.diag([1.1, 0.9, 1.25]), (12.5, -7.25, 3.125))
SECOND = affine(rotation(-0.1, 0.25, 0.05) @ np.diag([0.95, 1.05, 1.0]), (-3.5, 2.0, 8.75))

FIXED_DATE = "2000.01.01.00.00.00"
FIXED_IDENT = b"warpbench:mni_vtk.py:2000.01.01.00.00.00:0:1"
FIXED_HISTORY = b"Sat Jan  1 00:00:00 2000>>>Created by vtkMINCImageWriter\n"
TIGHT_TOLERANCE = 1e-6  # mm, VTK's InverseTolerance for the *_tight readings
TIGHT_ITERATIONS = 500

_VTK_MESSAGES = vtkStringOutputWindow()
_VTK_SEEN = [0]  # how much of _VTK_MESSAGES's text vtk_error has consumed


def quiet_vtk() -> None:
    """Send VTK's messages to a string (read by `vtk_error`) instead of stderr."""
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    vtkOutputWindow.SetInstance(_VTK_MESSAGES)


def vtk_error() -> str | None:
    """The first message VTK has given since the last call (its class line, addresses removed), or None."""
    text = _VTK_MESSAGES.GetOutput() or ""
    text, _VTK_SEEN[0] = text[_VTK_SEEN[0] :], len(text)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith(("ERROR: In ", "Warning: In "))]
    if not lines:
        return None
    return re.sub(r" \(0x[0-9a-f]+\)", "", lines[0])


def sitk_error(exc: Exception, path: Path) -> str:
    """A SimpleITK exception's first line and its `ITK ERROR` / `sitk::ERROR` line, addresses and the file's
    directory removed."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    first = lines[0] if lines else ""
    detail = next((ln for ln in lines[1:] if ln.startswith(("ITK ERROR", "sitk::ERROR"))), None)
    msg = first if detail is None else f"{first} {detail}"
    msg = msg.replace(str(path.resolve().parent) + "/", "").replace(str(path.parent) + "/", "")
    return re.sub(r"\(0x[0-9a-f]+\)", "", msg)


class _StderrToNull:
    """libminc prints its own messages on file descriptor 2 when SimpleITK fails: silence them."""

    def __enter__(self):
        sys.stderr.flush()
        self.saved = os.dup(2)
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)

    def __exit__(self, *exc):
        os.dup2(self.saved, 2)
        os.close(self.saved)


def floats(seq) -> list[float]:
    return [float(x) for x in seq]


# ---------------------------------------------------------------------------------------------------- inputs


def test_points() -> list[list[float]]:
    """20 RAS points over the grid's extent: 14 seeded ones inside it (rounded to 1/1000 mm), two grid nodes, a
    point half a spacing from a corner, one within a voxel of the +x face, and two outside the grid."""
    lo = np.array(GRID_ORIGIN)
    hi = lo + GRID_SPACING * (np.array(GRID_SIZE) - 1)
    rng = np.random.default_rng(20261207)
    inside = np.round(rng.uniform(lo + 2.0, hi - 2.0, size=(14, 3)), 3)
    extra = [
        [-5.0, 0.0, 5.0],  # node (2, 2, 2)
        [15.0, -10.0, -5.0],  # node (4, 1, 1)
        [-20.0, -15.0, -10.0],  # half a spacing inside the (0, 0, 0) corner
        [21.5, 3.25, 0.5],  # within a voxel of the +x face
        [31.5, -3.25, 2.0],  # outside (+x)
        [-12.0, 26.0, -19.5],  # outside (+y, -z)
    ]
    return [floats(p) for p in inside] + [floats(p) for p in extra]


def displacements() -> np.ndarray:
    """Smooth displacements (mm) on the grid, shape (nx, ny, nz, 3)."""
    i, j, k = np.meshgrid(*(np.arange(n, dtype=float) for n in GRID_SIZE), indexing="ij")
    return np.stack(
        [
            2.0 * np.sin(0.7 * i + 0.3 * k) + 0.25 * j,
            -1.5 * np.cos(0.9 * j) + 0.2 * i - 0.1 * k,
            1.2 * np.sin(1.1 * k + 0.4 * j) - 0.15 * i,
        ],
        axis=-1,
    )


def vtk_points(coords) -> vtkPoints:
    p = vtkPoints()
    p.SetDataTypeToDouble()
    for c in coords:
        p.InsertNextPoint(*c)
    return p


def vtk_matrix_transform(m: np.ndarray) -> vtkTransform:
    t = vtkTransform()
    t.SetMatrix([float(x) for x in np.asarray(m).flatten()])
    return t


def grid_transform() -> vtkGridTransform:
    img = vtkImageData()
    img.SetDimensions(*GRID_SIZE)
    img.SetSpacing(GRID_SPACING, GRID_SPACING, GRID_SPACING)
    img.SetOrigin(*GRID_ORIGIN)
    flat = displacements().transpose(2, 1, 0, 3).reshape(-1, 3)  # x fastest, as vtkImageData stores points
    img.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(flat), deep=1))
    g = vtkGridTransform()
    g.SetDisplacementGridData(img)
    g.SetInterpolationModeToCubic()
    return g


def tps_transform() -> vtkThinPlateSplineTransform:
    # vtkMNITransformWriter finds the dimensionality from the first landmark whose y is not 0 and only looks at
    # z there (it stops at 2-D otherwise and then refuses basis R): the first landmark has y and z not 0.
    source = [(-12.0, 8.0, 5.0), (14.0, -9.0, 3.0), (-6.0, -11.0, -8.0), (9.0, 12.0, -6.0), (2.0, 1.0, 11.0),
              (-15.0, -3.0, -10.0)]
    shift = [(1.5, -0.75, 0.5), (-1.0, 1.25, 0.75), (0.5, 0.5, -1.5), (-0.75, -1.0, 1.0), (1.25, 0.25, -0.5),
             (0.0, 1.5, 0.25)]
    target = [tuple(s + d for s, d in zip(p, q)) for p, q in zip(source, shift)]
    t = vtkThinPlateSplineTransform()
    t.SetSourceLandmarks(vtk_points(source))
    t.SetTargetLandmarks(vtk_points(target))
    t.SetBasisToR()
    return t


# ---------------------------------------------------------------------------------------------------- tags

TAG_FILES = {
    "pairs.tag": dict(
        vol1=[(-37.8125, 12.34375, 5.09375), (41.203125, -23.5, -11.671875), (-0.171875, 55.9375, 30.015625),
              (18.75, -60.140625, 2.0625), (-72.453125, -4.3125, -28.90625)],
        vol2=[(-35.125, 14.015625, 3.6875), (43.890625, -21.984375, -13.25), (1.546875, 57.25, 28.4375),
              (20.328125, -58.75, 0.828125), (-70.0625, -2.703125, -30.375)],
        labels=["anterior commissure", "posterior commissure", "left lateral ventricle tip",
                "right eye centre", "4th ventricle"],
    ),
    "pairs_ids.tag": dict(
        vol1=[(-12.34, 56.78, -9.01), (23.45, -67.89, 10.12), (-34.56, -7.8, 90.12), (0.1, 0.2, -0.3)],
        vol2=[(-11.1, 57.9, -8.2), (24.6, -66.05, 11.7), (-33.3, -6.45, 91.4), (1.05, 0.7, 0.15)],
        weights=[1.0, 0.5, 2.25, 0.0],
        structure_ids=[1, 2, 7, -1],
        patient_ids=[101, 101, 102, -1],
        labels=["AC", "PC", "vertex", "origin"],
    ),
    "pairs_nolabels.tag": dict(
        vol1=[(10.5, -20.25, 30.125), (-40.0625, 50.5, -60.75), (70.875, 80.3125, -90.5), (-1.5, -2.25, -3.125)],
        vol2=[(11.25, -19.5, 31.0), (-39.5, 51.125, -59.875), (71.625, 81.0, -89.75), (-0.75, -1.5, -2.375)],
    ),
    "one_volume.tag": dict(
        vol1=[(-23.5625, 17.125, 40.0), (0.0, -35.75, -12.375), (61.4375, 2.5, -7.8125)],
        labels=["nasion", "inion", "left tragus"],
    ),
    "comments.tag": dict(
        vol1=[(5.5, -6.6, 7.7), (-8.8, 9.9, -10.1), (11.11, -12.12, 13.13)],
        vol2=[(6.0, -6.1, 8.2), (-8.3, 10.4, -9.6), (11.6, -11.62, 13.63)],
        labels=["a", "b", "c"],
        comments="Volume 1: subject01_t1.mnc\nVolume 2: icbm152_t1.mnc\n%written by data-scripts/mni_vtk.py",
    ),
}

HAND_WRITTEN_TAG = """MNI Tag Point File
Volumes = 2;
%Volume: /data/subject01/t1.mnc
%Volume: /data/models/icbm_avg_152_t1_tal_lin.mnc

Points =
 -22.6734561920166 19.0250015258789 -4.51220703125 -23.1 18.25 -5.875 "AC"
 -22.4124908447266 -7.85302734375 -3.03125 -22.975 -8.8 -4.4 "PC"
 31.1999999999999 -54.3 12.0000000000001 30.25 -55 11.5 "right_cuneus"
 -45.001 60.125 33.3333333333333 -44.5 61 32.75 ""
 0.5 -0.25 70.875 1 0 71.5 "vertex";
"""


def write_tag(path: Path, spec: dict) -> None:
    w = vtkMNITagPointWriter()
    w.SetFileName(str(path))
    w.SetPoints(0, vtk_points(spec["vol1"]))
    if "vol2" in spec:
        w.SetPoints(1, vtk_points(spec["vol2"]))
    if "labels" in spec:
        a = vtkStringArray()
        for s in spec["labels"]:
            a.InsertNextValue(s)
        w.SetLabelText(a)
    if "weights" in spec:
        a = vtkDoubleArray()
        for v in spec["weights"]:
            a.InsertNextValue(v)
        w.SetWeights(a)
    for key, setter in (("structure_ids", w.SetStructureIds), ("patient_ids", w.SetPatientIds)):
        if key in spec:
            a = vtkIntArray()
            for v in spec[key]:
                a.InsertNextValue(v)
            setter(a)
    if "comments" in spec:
        w.SetComments(spec["comments"])
    w.Write()


def read_tag(path: Path) -> dict:
    vtk_error()
    r = vtkMNITagPointReader()
    r.SetFileName(str(path))
    r.Update()
    err = vtk_error()
    n = r.GetNumberOfVolumes()
    pts = []
    dtype = None
    for v in range(n):
        p = r.GetPoints(v)
        if p is None:
            pts.append(None)
            continue
        dtype = p.GetData().GetDataTypeAsString()
        pts.append([floats(p.GetPoint(i)) for i in range(p.GetNumberOfPoints())])

    def arr(a, conv):
        return None if a is None else [conv(a.GetValue(i)) for i in range(a.GetNumberOfValues())]

    return {
        "error": err,
        "volumes": n,
        "points": pts,
        "labels": arr(r.GetLabelText(), str),
        "weights": arr(r.GetWeights(), float),
        "structure_ids": arr(r.GetStructureIds(), int),
        "patient_ids": arr(r.GetPatientIds(), int),
        "comments": r.GetComments(),
        "vtk_points_dtype": {"float": "float32", "double": "float64"}.get(dtype, dtype),
    }


# ---------------------------------------------------------------------------------------------------- transforms


def write_xfm(path: Path, *transforms, comments: str | None = None) -> None:
    w = vtkMNITransformWriter()
    w.SetFileName(str(path))
    for t in transforms:
        w.AddTransform(t)
    if comments:
        w.SetComments(comments)
    vtk_error()
    w.Write()
    err = vtk_error()
    assert err is None, f"{path.name}: {err}"
    text = path.read_text()
    fixed, n = re.subn(r"^% Creation time: \d{4}(\.\d\d){5}$", f"% Creation time: {FIXED_DATE}", text, flags=re.M)
    assert n == 1, f"{path.name}: no creation time line"
    path.write_text(fixed)


def _pad4(n: int) -> int:
    return (n + 3) & ~3


_NC_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 4, 6: 8}  # byte, char, short, int, float, double


def normalise_netcdf(path: Path) -> None:
    """Rewrite the global `ident` and `history` attributes of a netCDF classic file (CDF-1 or CDF-2) with fixed
    values; every variable's begin offset moves by the change in header length, everything else is kept."""
    raw = path.read_bytes()
    assert raw[:3] == b"CDF" and raw[3] in (1, 2), f"{path.name}: not netCDF classic"
    off_size = 4 if raw[3] == 1 else 8
    pos = 8

    def u32(p):
        return struct.unpack_from(">I", raw, p)[0]

    def name_end(p):
        return p + 4 + _pad4(u32(p))

    # dimensions
    tag, n = u32(pos), u32(pos + 4)
    pos += 8
    for _ in range(n if tag else 0):
        pos = name_end(pos) + 4
    # global attributes: rebuilt
    gatt_start = pos
    tag, n = u32(pos), u32(pos + 4)
    pos += 8
    atts = []
    for _ in range(n if tag else 0):
        ne = name_end(pos)
        name = raw[pos + 4 : pos + 4 + u32(pos)]
        typ, count = u32(ne), u32(ne + 4)
        vlen = count * _NC_SIZES[typ]
        value = raw[ne + 8 : ne + 8 + vlen]
        atts.append((name, typ, value))
        pos = ne + 8 + _pad4(vlen)
    gatt_end = pos
    new_atts = []
    for name, typ, value in atts:
        if name == b"ident":
            value = FIXED_IDENT
        elif name == b"history":
            value = FIXED_HISTORY
        new_atts.append((name, typ, value))
    block = struct.pack(">II", 0x0C if new_atts else 0, len(new_atts))
    for name, typ, value in new_atts:
        block += struct.pack(">I", len(name)) + name + bytes(_pad4(len(name)) - len(name))
        count = len(value) // _NC_SIZES[typ]
        block += struct.pack(">II", typ, count) + value + bytes(_pad4(len(value)) - len(value))
    delta = len(block) - (gatt_end - gatt_start)
    out = bytearray(raw[:gatt_start] + block + raw[gatt_end:])
    # variables: shift begin offsets (positions after gatt_end move by delta)
    pos = gatt_end + delta
    tag, n = struct.unpack_from(">II", out, pos)
    pos += 8
    for _ in range(n if tag else 0):
        pos = pos + 4 + _pad4(struct.unpack_from(">I", out, pos)[0])
        ndims = struct.unpack_from(">I", out, pos)[0]
        pos += 4 + 4 * ndims
        atag, na = struct.unpack_from(">II", out, pos)
        pos += 8
        for _ in range(na if atag else 0):
            pos = pos + 4 + _pad4(struct.unpack_from(">I", out, pos)[0])
            typ, count = struct.unpack_from(">II", out, pos)
            pos += 8 + _pad4(count * _NC_SIZES[typ])
        pos += 8  # nc_type, vsize
        fmt = ">I" if off_size == 4 else ">Q"
        begin = struct.unpack_from(fmt, out, pos)[0]
        struct.pack_into(fmt, out, pos, begin + delta)
        pos += off_size
    path.write_bytes(bytes(out))


def grid_entry(path: Path, fmt: str, dims: list, data: np.ndarray, att) -> dict:
    """One grid volume's description: `att(dimension, key)` reads a dimension's attribute (None when absent)."""
    spatial = [d for d in dims if d != "vector_dimension"]
    return {
        "file": path.name,
        "format": fmt,
        "dimorder": dims,
        "shape": list(data.shape),
        "dtype": data.dtype.str,
        "start": {d: att(d, "start") for d in spatial},
        "step": {d: att(d, "step") for d in spatial},
        "direction_cosines": {d: att(d, "direction_cosines") for d in spatial},
        "values": floats(data.flatten()),
    }


def number_or_list(v):
    return floats(np.atleast_1d(v)) if np.ndim(v) else float(v)


def describe_grid_volume(path: Path) -> dict:
    """The displacement volume as stored: MINC 1 through scipy's netCDF reader, MINC 2 through h5py."""
    head = path.read_bytes()[:4]
    if head[:3] == b"CDF":
        with netcdf_file(str(path), "r", mmap=False) as f:
            img = f.variables["image"]

            def att(d, key):
                if d not in f.variables or key not in f.variables[d]._attributes:
                    return None
                return number_or_list(f.variables[d]._attributes[key])

            return grid_entry(path, f"MINC1 (netCDF CDF-{head[3]})", list(img.dimensions), np.array(img.data), att)
    with h5py.File(path, "r") as f:
        ds = f["minc-2.0/image/0/image"]

        def att(d, key):
            a = f[f"minc-2.0/dimensions/{d}"].attrs.get(key)
            return None if a is None else number_or_list(a)

        return grid_entry(path, "MINC2 (HDF5)", ds.attrs["dimorder"].decode().split(","), ds[()], att)


def read_xfm_vtk(path: Path, points) -> dict:
    vtk_error()
    r = vtkMNITransformReader()
    r.SetFileName(str(path))
    r.Update()
    err = vtk_error()
    t = r.GetTransform()
    n = r.GetNumberOfTransforms()
    members = [r.GetNthTransform(i) for i in range(n)]
    out = {
        "error": err,
        "class": None if t is None else t.GetClassName(),
        "classes": [m.GetClassName() for m in members],
        "inverse_flags": [int(m.GetInverseFlag()) if hasattr(m, "GetInverseFlag") else None for m in members],
        "comments": r.GetComments(),
        "points": None,
        "inverse_points": None,
        "inverse_tolerance": None,
    }
    for m in members:  # a grid whose volume VTK could not read has no displacements to apply
        if isinstance(m, vtkGridTransform):
            grid = m.GetDisplacementGrid()
            if grid is None or grid.GetPointData().GetScalars() is None:
                out["error"] = out["error"] or f"no displacement grid read from {path.name}"
                return out
    if err is not None or t is None:
        return out
    out["points"] = [floats(t.TransformPoint(*p)) for p in points]
    out["inverse_points"] = [floats(t.GetInverse().TransformPoint(*p)) for p in points]
    err = vtk_error()
    if err is not None:
        out["error"] = err
    warps = [m for m in members if isinstance(m, (vtkGridTransform, vtkThinPlateSplineTransform))]
    if warps:
        # VTK's iteration at the reader's tolerance, then again at TIGHT_TOLERANCE (on copies of the members)
        out["inverse_tolerance"] = [float(m.GetInverseTolerance()) for m in warps]
        tight = vtkGeneralTransform()
        tight.PostMultiply()
        for m in members:
            c = m.MakeTransform()
            c.DeepCopy(m)
            if isinstance(c, (vtkGridTransform, vtkThinPlateSplineTransform)):
                c.SetInverseTolerance(TIGHT_TOLERANCE)
                c.SetInverseIterations(TIGHT_ITERATIONS)
            tight.Concatenate(c)
        out["points_tight"] = [floats(tight.TransformPoint(*p)) for p in points]
        out["inverse_points_tight"] = [floats(tight.GetInverse().TransformPoint(*p)) for p in points]
        out["tight_error"] = vtk_error()
    return out


def read_xfm_sitk(path: Path, points) -> dict:
    out = {"error": None, "class": None, "members": None, "points": None, "inverse_points": None,
           "inverse_error": None}
    try:
        with _StderrToNull():
            t = sitk.ReadTransform(str(path))
    except Exception as exc:  # noqa: BLE001  (SimpleITK raises RuntimeError)
        out["error"] = sitk_error(exc, path)
        return out
    out["class"] = t.GetName()
    if t.GetName() == "CompositeTransform":
        c = sitk.CompositeTransform(t)
        out["members"] = [c.GetNthTransform(i).GetName() for i in range(c.GetNumberOfTransforms())]
    out["points"] = [floats(t.TransformPoint(tuple(p))) for p in points]
    try:
        inv = t.GetInverse()
        out["inverse_points"] = [floats(inv.TransformPoint(tuple(p))) for p in points]
    except Exception as exc:  # noqa: BLE001
        out["inverse_error"] = sitk_error(exc, path)
    return out


def grid_volume_of(path: Path) -> Path | None:
    m = re.search(r"^\s*Displacement_Volume\s*=\s*([^;]+?)\s*;", path.read_text(), flags=re.M)
    return None if m is None else path.parent / m.group(1)


def write_sitk_grid(path: Path) -> None:
    """sitk.WriteTransform of the grid as a DisplacementFieldTransform (.xfm + MINC 2 grid), with $LOGNAME padded
    so that libminc's ident is minc_fixtures.IDENT_LEN bytes long (minc_fixtures.with_fixed_ident), then the grid
    normalised by minc_fixtures.normalise_hdf5."""
    from minc_fixtures import normalise_hdf5, with_fixed_ident

    field = sitk.GetImageFromArray(np.ascontiguousarray(displacements().transpose(2, 1, 0, 3)), isVector=True)
    field.SetSpacing((GRID_SPACING,) * 3)
    field.SetOrigin(GRID_ORIGIN)
    tx = sitk.DisplacementFieldTransform(sitk.Cast(field, sitk.sitkVectorFloat64))
    grid = path.parent / f"{path.stem}_grid_0.mnc"
    with_fixed_ident(lambda: sitk.WriteTransform(tx, str(path)), grid)
    normalise_hdf5(grid)


# ---------------------------------------------------------------------------------------------------- driver


def make() -> None:
    quiet_vtk()
    OUT.mkdir(parents=True, exist_ok=True)
    points = test_points()
    reference: dict = {
        "readers": {"vtk": vtkVersion.GetVTKVersion(), "SimpleITK": sitk.Version_VersionString()},
        "test_points": points,
        "tags": [],
        "transforms": [],
    }

    for name, spec in TAG_FILES.items():
        write_tag(OUT / name, spec)
        seen = read_tag(OUT / name)
        assert seen["error"] is None, f"{name}: {seen['error']}"
        assert seen["volumes"] == (2 if "vol2" in spec else 1)
        for got, want in zip(seen["points"], [spec["vol1"], spec.get("vol2")]):
            assert np.allclose(got, want, rtol=1e-6, atol=1e-5), name
        reference["tags"].append({"file": name, "source": f"vtkMNITagPointWriter (VTK {vtkVersion.GetVTKVersion()})",
                                  **seen})
    (OUT / "hand_written.tag").write_text(HAND_WRITTEN_TAG)
    seen = read_tag(OUT / "hand_written.tag")
    assert seen["error"] is None and seen["volumes"] == 2 and len(seen["points"][0]) == 5, seen
    reference["tags"].append({"file": "hand_written.tag", "source": "data-scripts/mni_vtk.py (volume_io's layout)",
                              **seen})

    lin = vtk_matrix_transform(LINEAR)
    second = vtk_matrix_transform(SECOND)
    write_xfm(OUT / "linear.xfm", lin)
    inv_probe = vtkTransform()
    inv_probe.SetMatrix(lin.GetMatrix())
    inv_probe.Inverse()
    write_xfm(OUT / "linear_inverted.xfm", inv_probe)
    assert "Invert_Flag" not in (OUT / "linear_inverted.xfm").read_text(), "VTK wrote an Invert_Flag for a linear"
    text = (OUT / "linear.xfm").read_text()
    (OUT / "linear_inverted.xfm").write_text(
        text.replace("Transform_Type = Linear;\n", "Transform_Type = Linear;\nInvert_Flag = True;\n", 1))

    general = vtkGeneralTransform()
    general.PostMultiply()
    general.Concatenate(lin)
    general.Concatenate(second)
    write_xfm(OUT / "concatenated.xfm", general)

    grid = grid_transform()
    write_xfm(OUT / "grid.xfm", grid)
    grid_inv = grid_transform()
    grid_inv.Inverse()
    write_xfm(OUT / "grid_inverted.xfm", grid_inv)
    for name in ("grid.xfm", "grid_inverted.xfm"):
        normalise_netcdf(grid_volume_of(OUT / name))
    write_xfm(OUT / "tps.xfm", tps_transform())
    write_sitk_grid(OUT / "grid_itk.xfm")

    sources = {
        "linear.xfm": "vtkMNITransformWriter",
        "linear_inverted.xfm": "vtkMNITransformWriter's linear.xfm, Invert_Flag inserted by the script",
        "concatenated.xfm": "vtkMNITransformWriter (a vtkGeneralTransform of two vtkTransforms)",
        "grid.xfm": "vtkMNITransformWriter (vtkGridTransform; grid by vtkMINCImageWriter, ident/history fixed)",
        "grid_inverted.xfm": "vtkMNITransformWriter (inverted vtkGridTransform; grid by vtkMINCImageWriter, "
                             "ident/history fixed)",
        "tps.xfm": "vtkMNITransformWriter (vtkThinPlateSplineTransform, basis R)",
        "grid_itk.xfm": f"SimpleITK {sitk.Version_VersionString()} WriteTransform (DisplacementFieldTransform; "
                        "MINC 2 grid, normalised)",
    }
    for name, source in sources.items():
        path = OUT / name
        vol = grid_volume_of(path)
        entry = {
            "file": name,
            "files": [name] + ([vol.name] if vol else []),
            "source": source,
            "vtk": read_xfm_vtk(path, points),
            "sitk": read_xfm_sitk(path, points),
            "grid_volume": describe_grid_volume(vol) if vol else None,
        }
        reference["transforms"].append(entry)
    check_readings(reference)

    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    for p in sorted(OUT.iterdir()):
        print(f"{p.name}: {p.stat().st_size} bytes")


def check_readings(reference: dict) -> None:
    """What the fixtures must show: the readings that should agree do."""
    pts = np.array(reference["test_points"])
    by = {e["file"]: e for e in reference["transforms"]}
    hom = np.c_[pts, np.ones(len(pts))]
    want = {
        "linear.xfm": (hom @ LINEAR.T)[:, :3],
        "linear_inverted.xfm": (hom @ np.linalg.inv(LINEAR).T)[:, :3],
        "concatenated.xfm": (hom @ (SECOND @ LINEAR).T)[:, :3],
    }
    for name, w in want.items():
        for reader in ("vtk", "sitk"):
            got = by[name][reader]["points"]
            assert got is not None and np.allclose(got, w, atol=1e-9), f"{name}: {reader} differs from the matrix"
    # the grid: VTK reads the MINC 1 grid, SimpleITK the MINC 2 one; at the grid nodes both give the stored
    # displacement
    nodes = [i for i, p in enumerate(reference["test_points"]) if p in ([-5.0, 0.0, 5.0], [15.0, -10.0, -5.0])]
    vtk_grid = np.array(by["grid.xfm"]["vtk"]["points"])
    itk_grid = np.array(by["grid_itk.xfm"]["sitk"]["points"])
    assert np.allclose(vtk_grid[nodes], itk_grid[nodes], atol=1e-9), "grid nodes differ"
    d = displacements()
    for i in nodes:
        idx = tuple(int(round((c - o) / GRID_SPACING)) for c, o in zip(pts[i], GRID_ORIGIN))
        assert np.allclose(vtk_grid[i], pts[i] + d[idx], atol=1e-9), "grid node value"
    # the inverted grid is the grid's inverse (VTK: the same iteration)
    assert np.allclose(by["grid_inverted.xfm"]["vtk"]["points"], by["grid.xfm"]["vtk"]["inverse_points"])
    # the tight inverses map back onto the test points
    for name in ("grid.xfm", "tps.xfm"):
        r = vtkMNITransformReader()
        r.SetFileName(str(OUT / name))
        r.Update()
        t = r.GetTransform()
        back = [t.TransformPoint(*p) for p in by[name]["vtk"]["inverse_points_tight"]]
        assert np.allclose(back, pts, atol=1e-5), f"{name}: tight inverse"


def check(paths: list[str]) -> None:
    quiet_vtk()
    points = test_points()
    out = []
    for p in paths:
        path = Path(p)
        if path.suffix.lower() == ".tag":
            out.append({"file": p, **read_tag(path)})
        else:
            vol = grid_volume_of(path) if path.exists() else None
            out.append({
                "file": p,
                "test_points": points,
                "vtk": read_xfm_vtk(path, points),
                "sitk": read_xfm_sitk(path, points),
                "grid_volume": describe_grid_volume(vol) if vol is not None and vol.exists() else None,
            })
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", nargs="+", metavar="FILE", help="print what VTK and SimpleITK read from each FILE")
    args = ap.parse_args()
    if args.check:
        check(args.check)
    else:
        make()


if __name__ == "__main__":
    main()
