#!/usr/bin/env python3
"""ITK's reading of the transform files `warpbench transform` writes, for crates/app/tests/tfm_cli.rs.

For each case (affine, TPS λ = 0, TPS λ = 2, hierarchical B-spline with 2 levels) on the fixed volume
tests/data/nifti/avg152T1_LR_nifti.nii (fixed and moving) and the pairs tests/data/itk/field_pairs.csv:

1. `warpbench transform` writes the .tfm;
2. ITK maps 10 000 Halton points of the fixed volume's voxel-centre box through it: the affine and B-spline files
   through `SimpleITK.ReadTransform` + `TransformPoint`; the thin-plate spline (which neither SimpleITK nor ITK's
   Python wrapping registers with ITK's transform factory, so `ReadTransform` refuses it) through
   `itk.ThinPlateSplineKernelTransform[itk.D, 3]` given the file's Parameters and FixedParameters as ITK's
   `TransformFileReader` would hand them (`SetParameters`, `SetFixedParameters`, then `ComputeWMatrix`);
3. `warpbench points --from fixed` maps the same points by warpbench's pull-back u = moving_from_fixed;
4. the script asserts the two agree within 1e-4 mm at all 10 000 points and prints the largest difference.

It writes tests/data/itk/tfm_reference.json: per case the command-line flags, the ITK class, the largest difference
over the 10 000 points, and ITK's output at the first 300 points (the points themselves once, rounded to 1e-6 mm as
they were given to both programs). Deterministic: a rerun writes the same bytes.

Run from the repository root, with SimpleITK==2.5.7 and itk==5.4.7 installed in the Python that runs it:

    cargo build --release -p warpbench-app
    python3 data-scripts/itk_tfm_ref.py target/release/warpbench
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import itk
import numpy as np
import SimpleITK as sitk

ROOT = Path(__file__).resolve().parent.parent
FIXED = ROOT / "tests" / "data" / "nifti" / "avg152T1_LR_nifti.nii"
PAIRS = ROOT / "tests" / "data" / "itk" / "field_pairs.csv"
OUT = ROOT / "tests" / "data" / "itk" / "tfm_reference.json"
N_POINTS = 10_000
N_RECORDED = 300
TOLERANCE_MM = 1e-4
CASES = [
    ("affine", ["--method", "affine"]),
    ("tps", ["--method", "tps"]),
    ("tps_stiffness_2", ["--method", "tps", "--stiffness", "2"]),
    ("hbspline_2_levels", ["--method", "hbspline", "--levels", "2"]),
]


def radical_inverse(n: int, base: int) -> float:
    inv, f = 0.0, 1.0 / base
    while n > 0:
        inv += f * (n % base)
        n //= base
        f /= base
    return inv


def halton_points() -> np.ndarray:
    """Points 1..N of the Halton sequence (bases 2, 3, 5) over the fixed volume's voxel-centre box, in LPS mm."""
    image = sitk.ReadImage(str(FIXED))
    size = image.GetSize()
    corners = np.array(
        [
            image.TransformContinuousIndexToPhysicalPoint([float(c[0]), float(c[1]), float(c[2])])
            for c in np.array(np.meshgrid(*[[0, s - 1] for s in size])).T.reshape(-1, 3)
        ]
    )
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    unit = np.array([[radical_inverse(n, b) for b in (2, 3, 5)] for n in range(1, N_POINTS + 1)])
    return np.round(lo + unit * (hi - lo), 6)


def tfm_fields(path: Path) -> tuple[str, list[float], list[float]]:
    """The Transform class, Parameters and FixedParameters of a one-transform ITK file, read as text."""
    fields = {}
    for line in path.read_text().splitlines():
        if ":" in line and not line.startswith("#"):
            key, value = line.split(":", 1)
            fields[key.strip()] = value.split()
    return fields["Transform"][0], [float(v) for v in fields["Parameters"]], [
        float(v) for v in fields["FixedParameters"]
    ]


def itk_outputs(path: Path, points: np.ndarray) -> tuple[str, np.ndarray]:
    cls, params, fixed_params = tfm_fields(path)
    if cls.startswith("ThinPlateSplineKernelTransform"):
        tps = itk.ThinPlateSplineKernelTransform[itk.D, 3].New()
        p = itk.OptimizerParameters[itk.D](len(params))
        for i, v in enumerate(params):
            p[i] = v
        tps.SetParameters(p)
        f = itk.OptimizerParameters[itk.D](len(fixed_params))
        for i, v in enumerate(fixed_params):
            f[i] = v
        tps.SetFixedParameters(f)
        tps.ComputeWMatrix()
        transform_point = lambda x: tps.TransformPoint(itk.Point[itk.D, 3]([float(v) for v in x]))  # noqa: E731
    else:
        t = sitk.ReadTransform(str(path))
        transform_point = lambda x: t.TransformPoint([float(v) for v in x])  # noqa: E731
    return cls, np.array([[float(c) for c in transform_point(x)] for x in points])


def warpbench_outputs(exe: str, case_flags: list[str], points_csv: Path, out_csv: Path) -> np.ndarray:
    subprocess.run(
        [exe, "points", "--fixed", str(FIXED), "--moving", str(FIXED), "--landmarks", str(PAIRS), *case_flags,
         "--from", "fixed", "--in", str(points_csv), "--out", str(out_csv), "--quiet", "--force"],
        check=True,
    )
    with out_csv.open() as f:
        return np.array([[float(v) for v in row[:3]] for row in csv.reader(f)])


def main() -> None:
    exe = sys.argv[1]
    points = halton_points()
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        points_csv = Path(tmp) / "points.csv"
        points_csv.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points.tolist()))
        for name, flags in CASES:
            tfm = Path(tmp) / f"{name}.tfm"
            subprocess.run(
                [exe, "transform", "--fixed", str(FIXED), "--moving", str(FIXED), "--landmarks", str(PAIRS), *flags,
                 "--out", str(tfm), "--quiet"],
                check=True,
            )
            cls, by_itk = itk_outputs(tfm, points)
            by_warpbench = warpbench_outputs(exe, flags, points_csv, Path(tmp) / f"{name}_u.csv")
            moved = np.linalg.norm(by_itk - points, axis=1).max()
            diff = float(np.linalg.norm(by_itk - by_warpbench, axis=1).max())
            print(f"{name}: {cls}, max |ITK − warpbench| {diff:.3g} mm over {N_POINTS} points (max |T(x) − x| {moved:.3g} mm)")
            assert diff <= TOLERANCE_MM, name
            cases.append(
                {
                    "name": name,
                    "flags": flags,
                    "itk_class": cls,
                    "max_difference_mm": float(f"{diff:.3g}"),
                    "itk_outputs_lps": by_itk[:N_RECORDED].tolist(),
                }
            )
    doc = {
        "made_by": "data-scripts/itk_tfm_ref.py",
        "simpleitk": sitk.Version.VersionString(),
        "itk": itk.Version.GetITKVersion(),
        "fixed": "tests/data/nifti/avg152T1_LR_nifti.nii",
        "moving": "tests/data/nifti/avg152T1_LR_nifti.nii",
        "landmarks": "tests/data/itk/field_pairs.csv",
        "points_checked": N_POINTS,
        "points_lps": points[:N_RECORDED].tolist(),
        "cases": cases,
    }
    # One line per case keeps the file small and its diffs readable.
    head = {k: v for k, v in doc.items() if k not in ("points_lps", "cases")}
    lines = [json.dumps(head)[:-1] + ',', ' "points_lps": ' + json.dumps(doc["points_lps"]) + ',', ' "cases": [']
    lines += [' ' + json.dumps(c) + (',' if i + 1 < len(cases) else '') for i, c in enumerate(cases)]
    lines += [' ]', '}']
    OUT.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
