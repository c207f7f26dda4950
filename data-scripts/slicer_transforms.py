#!/usr/bin/env python3
"""Transform files as 3D Slicer saves them in their modeling direction, made from files ITK wrote, and ITK's maps.

Writes into tests/data/itk/:
- tps_itk.tfm, tps_itk.h5: ITK's ThinPlateSplineKernelTransform<double, 3> with the fixed points as its source
  landmarks and the moving points as its target ones, written by ITK's TransformFileWriter: a resampling transform,
  fixed -> moving, as ITK and every tool built on it store a transform.
- tps_slicer.tfm, tps_slicer.h5: what 3D Slicer saves for the thin-plate spline of a landmark registration (Fiducial
  Registration Wizard, Landmark Registration). Slicer's spline goes from the moving points (source) to the fixed ones
  (target), its "to parent" direction; Slicer saves a transform in its resampling ("from parent") direction, which is
  the inverse of that spline, and says so with its own class, InverseThinPlateSplineKernelTransform_double_3_3
  (vtkITKTransformConverter: SetITKThinPlateSplineTransformFromVTK writes that class for a VTK spline whose inverse
  flag is set, SetVTKThinPlateSplineTransformFromITK reads it back as the spline from source to target, inverted).
  That class is Slicer's subclass of ITK's and lives only in Slicer, so this script has ITK write the plain class
  with those landmarks and renames the class in the file: the TransformType dataset (h5py, as the variable-length
  ASCII string ITK writes) and the `Transform:` line (.tfm). Everything else in the files is ITK's.
- slicer_tps_reference.json: the moving and fixed points; query points; ITK's TransformPoint of the resampling spline
  (fixed -> moving) at the queries, and of Slicer's spline (moving -> fixed) at the same queries.
- h5_field_slicer_inverse.h5: h5_field.h5 (SimpleITK's DisplacementFieldTransform, data-scripts/itk_h5_sitk.py) under
  Slicer's class for a grid transform computed in its modeling direction, InverseDisplacementFieldTransform_double_3_3
  (vtkITKTransformConverter: SetITKOrientedGridTransformFromVTK writes it for a VTK grid whose inverse flag is set,
  SetVTKOrientedGridTransformFromITK reads it back as that grid, inverted): the field is Slicer's map from the moving
  space to the fixed one, and the resampling transform its inverse. Where SimpleITK maps points through h5_field.h5
  (h5_reference.json) is where Slicer's field maps moving points.

The points lie inside tests/data/itk/field_input_fixed.nii.gz's box (16 x 14 x 12 voxels of 2 mm, centred near the
origin), so that `warpbench points` can map them with that volume as both fixed and moving.

Run from the repository root (re-runnable: the values are deterministic, but HDF5 stamps the objects it writes with
the time, so a rerun's .h5 bytes differ):

    data-cache/venv/bin/python data-scripts/slicer_transforms.py

It installs the pinned wheels into data-cache/venv when an import fails (ITK's Python transform writer needs itk-io,
which needs itk-numerics and itk-filtering beside itk-core).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from itk_tps import itk_map, itk_spline

ITK_CORE_VERSION = "5.4.7"
ITK_MODULES = ["core", "numerics", "filtering", "io"]
H5PY_VERSION = "3.14.0"
SEED = 20261206
N_LANDMARKS = 10
N_QUERIES = 40
SLICER_CLASS = "InverseThinPlateSplineKernelTransform_double_3_3"
ITK_CLASS = "ThinPlateSplineKernelTransform_double_3_3"
FIELD_CLASS = "DisplacementFieldTransform_double_3_3"
SLICER_FIELD_CLASS = "InverseDisplacementFieldTransform_double_3_3"
ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "itk"


def imports():
    try:
        import h5py  # noqa: PLC0415
        import itk  # noqa: PLC0415
        import numpy  # noqa: PLC0415, F401
    except ImportError:
        subprocess.run(
            [sys.executable, "-m", "pip", "install", *(f"itk-{m}=={ITK_CORE_VERSION}" for m in ITK_MODULES),
             f"h5py=={H5PY_VERSION}"],
            check=True,
        )
        import h5py  # noqa: PLC0415
        import itk  # noqa: PLC0415
    if itk.Version.GetITKVersion() != ITK_CORE_VERSION:
        sys.exit(f"expected ITK {ITK_CORE_VERSION}, found {itk.Version.GetITKVersion()}")
    if h5py.__version__ != H5PY_VERSION:
        sys.exit(f"expected h5py {H5PY_VERSION}, found {h5py.__version__}")
    return itk, h5py


def rename_h5_class(h5py, path: Path, old_class: str, new_class: str) -> None:
    with h5py.File(path, "r+") as f:
        dataset = f["/TransformGroup/0/TransformType"]
        old = [s.decode() if isinstance(s, bytes) else s for s in dataset[()]]
        if old != [old_class]:
            sys.exit(f"{path}: expected TransformType [{old_class!r}], found {old!r}")
        dtype = dataset.dtype
        del f["/TransformGroup/0/TransformType"]
        f["/TransformGroup/0"].create_dataset("TransformType", data=[new_class.encode()], dtype=dtype)


def main() -> None:
    itk, h5py = imports()
    import numpy as np  # noqa: PLC0415

    rng = np.random.default_rng(SEED)
    moving = rng.uniform(-12.0, 12.0, (N_LANDMARKS, 3))
    angle = np.deg2rad(4.0)
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    fixed = moving @ rotation.T + np.array([0.8, -0.5, 0.3])
    fixed += 1.2 * np.sin(moving / 7.0)[:, [1, 2, 0]]
    queries = np.vstack([moving, fixed, rng.uniform(-12.0, 12.0, (N_QUERIES, 3))])

    resampling = itk_spline(itk, fixed, moving)
    itk.transformwrite([resampling], str(OUT / "tps_itk.tfm"))
    itk.transformwrite([resampling], str(OUT / "tps_itk.h5"))

    slicer_spline = itk_spline(itk, moving, fixed)
    itk.transformwrite([slicer_spline], str(OUT / "tps_slicer.tfm"))
    itk.transformwrite([slicer_spline], str(OUT / "tps_slicer.h5"))
    tfm = OUT / "tps_slicer.tfm"
    text = tfm.read_text()
    if text.count(f"Transform: {ITK_CLASS}") != 1:
        sys.exit(f"{tfm}: expected one `Transform: {ITK_CLASS}` line")
    tfm.write_text(text.replace(f"Transform: {ITK_CLASS}", f"Transform: {SLICER_CLASS}"))
    rename_h5_class(h5py, OUT / "tps_slicer.h5", ITK_CLASS, SLICER_CLASS)
    field = OUT / "h5_field_slicer_inverse.h5"
    shutil.copyfile(OUT / "h5_field.h5", field)
    rename_h5_class(h5py, field, FIELD_CLASS, SLICER_FIELD_CLASS)

    doc = {
        "generator": "data-scripts/slicer_transforms.py",
        "itk_version": itk.Version.GetITKVersion(),
        "h5py_version": h5py.__version__,
        "seed": SEED,
        "moving": moving.tolist(),
        "fixed": fixed.tolist(),
        "queries": queries.tolist(),
        "note": "queries: the moving points, the fixed points, then random points; moving_from_fixed is ITK's "
        "TransformPoint of the spline from the fixed to the moving points (tps_itk.*), fixed_from_moving of the "
        "spline from the moving to the fixed points (Slicer's spline in tps_slicer.*, before its inversion)",
        "moving_from_fixed": itk_map(itk, resampling, queries),
        "fixed_from_moving": itk_map(itk, slicer_spline, queries),
    }
    (OUT / "slicer_tps_reference.json").write_text(json.dumps(doc, separators=(",", ":")) + "\n")
    print(f"wrote tps_itk.{{tfm,h5}}, tps_slicer.{{tfm,h5}}, slicer_tps_reference.json, h5_field_slicer_inverse.h5 into {OUT}")


if __name__ == "__main__":
    main()
