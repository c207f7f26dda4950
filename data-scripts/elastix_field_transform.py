#!/usr/bin/env python3
"""elastix `DeformationFieldTransform` files, and where transformix maps points through them:
tests/data/elastix/field_nearest.txt, field_linear.txt and tests/data/elastix/transformix_field_transform.json.

The field is tests/data/metaimage/transformix_field.mhd (transformix's own `deformationField.mhd` of a B-spline over
an oblique 9×8×7 grid, written by data-scripts/elastix_field.py). Each parameter file names it relative to itself,
`../metaimage/transformix_field.mhd`, with `DeformationFieldInterpolationOrder` 0 (nearest voxel centre, elastix's
default) or 1 (trilinear), and gives the field's grid as the fixed grid. transformix (elastix 5 through itk-elastix
0.25.4, ITK 5.4.7), run from tests/data/elastix so that it finds the field, maps 120 points through each: drawn in
the field's box widened by one voxel on every side, in the field's own index space, so that some fall inside, some
in the half voxel past the outermost centres (where the outermost vectors are held) and some outside (where the
transform is the identity). The reference records them and transformix's `OutputPoint`s (printed to 6 decimals).

Deterministic: a rerun writes the same bytes. Run from the repository root, with itk-elastix==0.25.4 installed:

    data-cache/elastix-venv/bin/python data-scripts/elastix_field_transform.py
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import itk
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "elastix"
FIELD = ROOT / "tests" / "data" / "metaimage" / "transformix_field.mhd"
FIELD_NAME = "../metaimage/transformix_field.mhd"


def parameter_map(order: int) -> dict[str, list[str]]:
    """The B-spline's own parameter map (whose fixed grid is the field's, as transformix wrote the field over it),
    with its transform replaced by the field's."""
    bspline = itk.ParameterObject.New()
    bspline.ReadParameterFile(str(OUT / "bspline_oblique.txt"))
    m = {k: list(v) for k, v in bspline.GetParameterMap(0).items()
         if not k.startswith(("Grid", "BSpline", "TransformParameters", "UseCyclic"))}
    m.update({"Transform": ["DeformationFieldTransform"], "DeformationFieldFileName": [FIELD_NAME],
              "DeformationFieldInterpolationOrder": [str(order)], "NumberOfParameters": ["0"]})
    return m


def transformix_points(parameter_file: Path, points: list[list[float]], image: itk.Image) -> list[list[float]]:
    """transformix's `OutputPoint` for `points` (LPS mm), run from the parameter file's folder."""
    objects = itk.ParameterObject.New()
    objects.ReadParameterFile(str(parameter_file))
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        inputs = tmp / "inputpoints.txt"
        inputs.write_text("point\n%d\n" % len(points) + "".join(" ".join(repr(float(v)) for v in p) + "\n"
                                                             for p in points))
        os.chdir(parameter_file.parent)
        try:
            f = itk.TransformixFilter.New(Input=image, TransformParameterObject=objects)
            f.SetFixedPointSetFileName(str(inputs))
            f.SetOutputDirectory(str(tmp))
            f.SetComputeDeformationField(False)
            f.Update()
        finally:
            os.chdir(here)
        text = (tmp / "outputpoints.txt").read_text()
    out = [[float(v) for v in m.split()] for m in re.findall(r"OutputPoint = \[ ([^\]]*)\]", text)]
    assert len(out) == len(points)
    return out


def main() -> None:
    field = itk.imread(str(FIELD), itk.Vector[itk.F, 3])
    size = np.array([int(n) for n in field.GetLargestPossibleRegion().GetSize()], dtype=float)
    rng = np.random.default_rng(20261206)
    # Continuous indices in [−1.5, n + 0.5): one voxel past the buffer (which ends half a voxel past the centres).
    indices = rng.uniform(-1.5, size + 0.5, size=(120, 3))
    lps_from_index = itk.array_from_matrix(field.GetDirection()) @ np.diag(np.array(field.GetSpacing(), dtype=float))
    points = (np.array(field.GetOrigin(), dtype=float) + indices @ lps_from_index.T).tolist()
    image = itk.Image[itk.F, 3].New()
    image.SetRegions(field.GetLargestPossibleRegion())
    image.SetSpacing(field.GetSpacing())
    image.SetOrigin(field.GetOrigin())
    image.SetDirection(field.GetDirection())
    image.Allocate()
    image.FillBuffer(0.0)
    reference: dict = {"made_by": "data-scripts/elastix_field_transform.py", "itk": itk.Version.GetITKVersion(),
                       "itk_elastix": "0.25.4", "field": FIELD_NAME, "points_lps": points, "files": []}
    for name, order in [("field_nearest.txt", 0), ("field_linear.txt", 1)]:
        m = itk.ParameterObject.New()
        m.AddParameterMap(parameter_map(order))
        itk.ParameterObject.WriteParameterFile(m.GetParameterMap(0), str(OUT / name))
        mapped = transformix_points(OUT / name, points, image)
        moved = [float(np.linalg.norm(np.subtract(a, b))) for a, b in zip(mapped, points)]
        still = sum(d < 1e-5 for d in moved)
        print(f"{name}: transformix moves the points by up to {max(moved):.2f} mm; {still} of {len(points)} stay")
        reference["files"].append({"file": name, "order": order, "transformix_lps": mapped})
    (OUT / "transformix_field_transform.json").write_text(json.dumps(reference) + "\n")


if __name__ == "__main__":
    main()
