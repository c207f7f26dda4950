#!/usr/bin/env python3
"""How long `warpbench register` takes on a 256³ pair (issue 31: the window's refinement of a 256³ pair in at most
10 s on 2 cores), as whole processes, medians.

The pair: Colin27 (tests/data/nifti/ch2.nii.gz) resampled by SimpleITK (linear) onto 256³ voxels spanning its box
(0.71 × 0.85 × 0.71 mm), as the fixed volume; as the moving volume the same grid with the intensities remapped as a
second modality's (v ↦ 1000 (1 − t)^1.5 + 50 t) and shifted by 2 mm, so there is something to register. The
registration runs with its defaults from the identity (no landmarks), the work the window's *Refine by intensities*
does (the window then samples the field on 128³ points; the command writes it on all 256³ voxels, which `--json`'s
`register_s` leaves out).

Run from the repository root after `cargo build --release -p warpbench-app`:

    data-cache/venv/bin/python data-scripts/register_speed.py [--rounds 3]
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from compare_sitk_align import machine

ROOT = Path(__file__).resolve().parent.parent
T1 = ROOT / "tests/data/nifti/ch2.nii.gz"


def make_pair(tmp: Path) -> tuple[Path, Path]:
    import SimpleITK as sitk

    t1 = sitk.ReadImage(str(T1), sitk.sitkFloat32)
    size = np.array(t1.GetSize())
    spacing = (size - 1) * np.array(t1.GetSpacing()) / 255.0
    grid = sitk.Resample(t1, [256] * 3, sitk.Transform(), sitk.sitkLinear, t1.GetOrigin(), spacing.tolist(),
                         t1.GetDirection(), 0.0, sitk.sitkFloat32)
    shift = sitk.TranslationTransform(3, [2.0, -1.0, 1.0])
    moved = sitk.Resample(grid, grid, shift, sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    a = sitk.GetArrayFromImage(moved)
    t = (a - a.min()) / (a.max() - a.min())
    moving = sitk.GetImageFromArray((1000.0 * (1.0 - t) ** 1.5 + 50.0 * t).astype(np.float32))
    moving.CopyInformation(grid)
    fixed_path, moving_path = tmp / "fixed256.nii.gz", tmp / "moving256.nii.gz"
    sitk.WriteImage(grid, str(fixed_path))
    sitk.WriteImage(moving, str(moving_path))
    return fixed_path, moving_path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    binary = ROOT / "target/release/warpbench"
    if not binary.exists():
        sys.exit("build first: cargo build --release -p warpbench-app")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        fixed, moving = make_pair(tmp)
        walls, registers, levels = [], [], None
        for _ in range(args.rounds):
            start = time.perf_counter()
            run = subprocess.run([str(binary), "register", "--fixed", str(fixed), "--moving", str(moving),
                                  "--out-field", str(tmp / "field.nii.gz"), "--json", "--quiet", "--force"],
                                 check=True, capture_output=True, text=True)
            walls.append(time.perf_counter() - start)
            report = json.loads(run.stdout)
            registers.append(report["register_s"])
            levels = report["levels"]
        print(f"\n{datetime.date.today()}, {machine()}; 256³ pair, {args.rounds} runs, whole processes, medians")
        print(f"\nregistration {statistics.median(registers):.2f} s; whole process (reading, writing the 256³ field) "
              f"{statistics.median(walls):.2f} s")
        for level in levels or []:
            print(f"  shrink {level['shrink']}: {level['control_points']} control points, {level['samples']} samples, "
                  f"{level['iterations']} iterations, {level['evaluations']} evaluations, {level['seconds']:.2f} s, "
                  f"similarity {level['similarity_start']:.3f} → {level['similarity']:.3f}")


if __name__ == "__main__":
    main()
