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

Given the warpbench binary, it also checks what warpbench writes (and writes nothing to tests/data for it): a
session whose warp is tests/data/itk/field_input_field.nii.gz under no landmarks, given to `warpbench transform
--format elastix --out out/T.txt` in a scratch folder, which writes a DeformationFieldTransform naming
`out/T.field.mha`; transformix, run from that folder, maps 100 voxel centres of the fixed volume
(tests/data/itk/field_input_fixed.nii.gz) where `warpbench points --session --from fixed` maps them, within 1e-5 mm
(the figure is printed).

Deterministic: a rerun writes the same bytes. Run from the repository root, with itk-elastix==0.25.4 installed:

    data-cache/elastix-venv/bin/python data-scripts/elastix_field_transform.py [target/debug/warpbench]
"""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import itk
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "elastix"
FIELD = ROOT / "tests" / "data" / "metaimage" / "transformix_field.mhd"
FIELD_NAME = "../metaimage/transformix_field.mhd"
ITK_DATA = ROOT / "tests" / "data" / "itk"
AGREE_MM = 1e-5


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


def transformix_points(parameter_file: Path, points: list[list[float]], image: itk.Image,
                       run_in: Path | None = None) -> list[list[float]]:
    """transformix's `OutputPoint` for `points` (LPS mm), run from `run_in` (the parameter file's folder unless
    given), where it looks for the field the file names."""
    objects = itk.ParameterObject.New()
    objects.ReadParameterFile(str(parameter_file))
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        inputs = tmp / "inputpoints.txt"
        inputs.write_text("point\n%d\n" % len(points) + "".join(" ".join(repr(float(v)) for v in p) + "\n"
                                                             for p in points))
        os.chdir(run_in or parameter_file.parent)
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
    if len(sys.argv) > 1:
        check_written(str(Path(sys.argv[1]).resolve()))


def minimal_session(fixed: Path, moving: Path, field: Path) -> dict:
    """A warpbench session (schema warpbench-session/1) with no landmarks whose warp is `field`: the keys every
    session file has, with the window's defaults."""
    look = {"preset": "mr-t1", "window_low": 0.0, "window_high": 100.0, "visible": True}
    return {
        "schema": "warpbench-session/1", "fixed": str(fixed), "moving": str(moving), "landmarks": [],
        "settings": {"blend": "red-cyan", "mix_weight": 0.5, "checker_mm": 16.0, "shading": "iso",
                     "samples_per_voxel": 1.0, "method": "tps", "stiffness": 0.0, "bspline_levels": 4,
                     "control_texels": 64, "show_landmarks": True},
        "layers": [look, look],
        "camera": {"azimuth_deg": 0.0, "elevation_deg": 0.0, "zoom": 1.0, "target_lps": [0.0, 0.0, 0.0]},
        "slice_mm": [0.0, 0.0, 0.0], "clean_exit": True, "field": str(field),
    }


def check_written(exe: str) -> None:
    """transformix through the DeformationFieldTransform `warpbench transform --format elastix` writes for a session
    with a field, against warpbench's own pull-back, at voxel centres of the fixed grid."""
    fixed_path, moving_path = ITK_DATA / "field_input_fixed.nii.gz", ITK_DATA / "field_input_moving.nii.gz"
    fixed = itk.imread(str(fixed_path), itk.F)
    size = [int(n) for n in fixed.GetLargestPossibleRegion().GetSize()]
    rng = np.random.default_rng(20261206)
    centres = [list(fixed.TransformIndexToPhysicalPoint([int(rng.integers(0, n)) for n in size]))
               for _ in range(100)]
    volumes = ["--fixed", str(fixed_path), "--moving", str(moving_path)]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        session = tmp / "s.warpbench.json"
        session.write_text(json.dumps(minimal_session(fixed_path, moving_path, ITK_DATA / "field_input_field.nii.gz")))
        (tmp / "out").mkdir()
        subprocess.run([exe, "transform", *volumes, "--session", str(session), "--format", "elastix",
                        "--out", "out/T.txt", "--quiet"], check=True, cwd=tmp)
        assert '(DeformationFieldFileName "out/T.field.mha")' in (tmp / "out" / "T.txt").read_text()
        (tmp / "in.csv").write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in centres))
        subprocess.run([exe, "points", *volumes, "--session", str(session), "--from", "fixed", "--in", "in.csv",
                        "--out", "ours.csv", "--quiet"], check=True, cwd=tmp)
        with (tmp / "ours.csv").open() as f:
            ours = [[float(v) for v in row[:3]] for row in csv.reader(f)]
        theirs = transformix_points(tmp / "out" / "T.txt", centres, fixed, run_in=tmp)
    worst = float(np.abs(np.subtract(ours, theirs)).max())
    moved = max(float(np.linalg.norm(np.subtract(a, b))) for a, b in zip(theirs, centres))
    print(f"warpbench's DeformationFieldTransform: transformix vs warpbench's pull-back at {len(centres)} voxel "
          f"centres: {worst:.3g} mm (the points moved up to {moved:.2f} mm)")
    assert worst <= AGREE_MM, worst


if __name__ == "__main__":
    main()
