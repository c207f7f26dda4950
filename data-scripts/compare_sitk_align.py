#!/usr/bin/env python3
"""Side by side, in one run: `warpbench align` and SimpleITK's `ImageRegistrationMethod` (Mattes mutual information,
rigid, multi-resolution), as whole processes on the same pairs of a real head MRI and known rigid transforms.

The pairs: the fixed image is Colin27 (tests/data/nifti/ch2.nii.gz, 1 mm, 181×217×181). Each moving image is the
fixed one moved by a known rigid transform T (a rotation of up to 15° about a seeded axis through the head's centre,
then a shift of up to 20 mm), resampled by SimpleITK (linear) on its own grid (1.1 mm, axis-aligned, covering the
moved head), 0 outside the fixed image's box, written as float32 `.nii`; with `--remap` also a second copy with its
intensities remapped non-monotonically, v ↦ 255 · (|v − 90| / 164)^0.7, as a second modality's would be (tissue
near 90 goes dark, background bright).

The two pipelines, each one whole process (start, read both, register, write the `.tfm`):

- `warpbench`: `warpbench align --fixed F --moving M --out-tfm T.tfm --json --quiet` (defaults: 50 bins, 40 000
  samples per level, shrink 4, 2, 1);
- `sitk`: this script with `--pipeline sitk`: SimpleITK's documented multi-resolution set-up (the SimpleITK
  notebooks' "Registration Introduction"): `CenteredTransformInitializer(Euler3DTransform, MOMENTS)`, Mattes MI
  with 50 bins, random sampling 1 % (seeded), linear interpolation, scales from physical shift, shrink 4, 2, 1,
  smoothing σ 2, 1, 0 mm; with the regular-step gradient descent of SimpleITK's `ImageRegistrationMethod1`
  example (learning rate 2, minimum step 1e-4, 200 iterations, relaxation 0.5). The notebook's plain gradient
  descent (learning rate 1, 100 iterations, convergence 1e-6 over 10) stopped after about 10 iterations 16–46 mm
  from the truth on the first pair (MOMENTS or GEOMETRY start, 1 % or 5 % sampling), and a minimum step of 0.01
  left 0.59 mm: the set-up here is the most accurate of those tried, so the comparison is against SimpleITK at its
  best on these pairs, not at its fastest.

The rounds alternate the pipelines on each pair; the table shows each pipeline's median wall time per pair, the
median of the per-run ratios, and each result's error against T: RMS over the head (fixed voxels above 20) of
|T̂(x) − T(x)| in mm and the angle of the rotation between T̂ and T in degrees, read back from each `.tfm` with
SimpleITK.

Run from the repository root after `cargo build --release -p warpbench-app`:

    data-cache/venv/bin/python data-scripts/compare_sitk_align.py [--pairs 3] [--rounds 3] [--remap] [--keep DIR]

Versions measured: Python 3, nibabel 5.4.2, numpy 2.4.6, SimpleITK 2.5.7.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FIXED = ROOT / "tests/data/nifti/ch2.nii.gz"
SEED = 20261203
HEAD_THRESHOLD = 20.0


def rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * (k @ k)


def truths(n: int, centre: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """n seeded rigid pull-backs T(x) = R (x − c) + c + s, fixed → moving: (R, offset, description)."""
    rng = np.random.default_rng(SEED)
    out = []
    for i in range(n):
        angle = np.deg2rad(15.0 if i == 0 else rng.uniform(8.0, 15.0)) * rng.choice([-1.0, 1.0])
        axis = rng.normal(size=3)
        shift = rng.normal(size=3)
        shift *= (20.0 if i == 0 else rng.uniform(10.0, 20.0)) / np.linalg.norm(shift)
        r = rotation(axis, angle)
        offset = centre + shift - r @ centre
        out.append((r, offset, f"{np.rad2deg(abs(angle)):.1f}°, {np.linalg.norm(shift):.1f} mm"))
    return out


def affine(sitk, r: np.ndarray, offset: np.ndarray):
    t = sitk.AffineTransform(3)
    t.SetMatrix(r.flatten().tolist())
    t.SetTranslation(offset.tolist())
    return t


def make_pairs(tmp: Path, n: int, remap: bool) -> list[dict]:
    import SimpleITK as sitk

    fixed = sitk.ReadImage(str(FIXED), sitk.sitkFloat32)
    size = np.array(fixed.GetSize())
    centre = np.array(fixed.TransformContinuousIndexToPhysicalPoint(((size - 1) / 2.0).tolist()))
    corners = [np.array(fixed.TransformIndexToPhysicalPoint([int(c) for c in (size - 1) * np.array(b)]))
               for b in np.ndindex(2, 2, 2)]
    pairs = []
    for i, (r, offset, what) in enumerate(truths(n, centre)):
        moved = np.array([r @ c + offset for c in corners])
        lo, hi = moved.min(axis=0) - 2.0, moved.max(axis=0) + 2.0
        spacing = 1.1
        grid = [int(np.ceil((h - l) / spacing)) + 1 for l, h in zip(lo, hi)]
        # Resample's transform maps output (moving) points to input (fixed) points: T⁻¹.
        r_inv = r.T
        fixed_from_moving = affine(sitk, r_inv, -r_inv @ offset)
        moving = sitk.Resample(fixed, grid, fixed_from_moving, sitk.sitkLinear, lo.tolist(), [spacing] * 3,
                               [1, 0, 0, 0, 1, 0, 0, 0, 1], 0.0, sitk.sitkFloat32)
        variants = [("same", moving)]
        if remap:
            a = sitk.GetArrayFromImage(moving)
            b = 255.0 * (np.abs(a - 90.0) / 164.0) ** 0.7
            other = sitk.GetImageFromArray(b.astype(np.float32))
            other.CopyInformation(moving)
            variants.append(("remapped", other))
        for name, image in variants:
            path = tmp / f"moving_{i + 1}_{name}.nii"
            sitk.WriteImage(image, str(path))
            pairs.append({"name": f"{i + 1} ({what}, {name})", "path": path, "r": r, "offset": offset})
    return pairs


def run_sitk(fixed_path: Path, moving_path: Path, out: Path) -> None:
    import SimpleITK as sitk

    fixed = sitk.ReadImage(str(fixed_path), sitk.sitkFloat32)
    moving = sitk.ReadImage(str(moving_path), sitk.sitkFloat32)
    initial = sitk.CenteredTransformInitializer(fixed, moving, sitk.Euler3DTransform(),
                                                sitk.CenteredTransformInitializerFilter.MOMENTS)
    method = sitk.ImageRegistrationMethod()
    method.SetMetricAsMattesMutualInformation(numberOfHistogramBins=50)
    method.SetMetricSamplingStrategy(method.RANDOM)
    method.SetMetricSamplingPercentage(0.01, 1)
    method.SetInterpolator(sitk.sitkLinear)
    method.SetOptimizerAsRegularStepGradientDescent(learningRate=2.0, minStep=1e-4, numberOfIterations=200,
                                                    relaxationFactor=0.5)
    method.SetOptimizerScalesFromPhysicalShift()
    method.SetShrinkFactorsPerLevel(shrinkFactors=[4, 2, 1])
    method.SetSmoothingSigmasPerLevel(smoothingSigmas=[2, 1, 0])
    method.SmoothingSigmasAreSpecifiedInPhysicalUnitsOn()
    method.SetInitialTransform(initial, inPlace=False)
    result = method.Execute(fixed, moving)
    sitk.WriteTransform(result, str(out))


def errors(tfm: Path, r: np.ndarray, offset: np.ndarray, head: np.ndarray) -> tuple[float, float]:
    """RMS over `head` (N×3 fixed points) of |T̂(x) − T(x)| (mm) and the rotation angle between them (degrees)."""
    import SimpleITK as sitk

    t = sitk.ReadTransform(str(tfm))
    got = np.array([t.TransformPoint(p.tolist()) for p in head])
    want = head @ r.T + offset
    rms = float(np.sqrt(np.mean(np.sum((got - want) ** 2, axis=1))))
    # The linear part from the transform itself: differences of images of the unit vectors.
    o = np.array(t.TransformPoint([0.0, 0.0, 0.0]))
    m = np.stack([np.array(t.TransformPoint(e.tolist())) - o for e in np.eye(3)], axis=1)
    u, _, vt = np.linalg.svd(m @ r.T)
    rel = u @ vt
    angle = float(np.rad2deg(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1))))
    return rms, angle


def head_points() -> np.ndarray:
    import SimpleITK as sitk

    fixed = sitk.ReadImage(str(FIXED), sitk.sitkFloat32)
    a = sitk.GetArrayFromImage(fixed)  # z, y, x
    idx = np.argwhere(a > HEAD_THRESHOLD)[::97]  # every 97th head voxel: ~20 000 points
    return np.array([fixed.TransformIndexToPhysicalPoint([int(i[2]), int(i[1]), int(i[0])]) for i in idx])


def machine() -> str:
    model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                  if line.startswith("model name")), platform.processor())
    return f"{os.cpu_count()} cores, {model}, {platform.system()} {platform.machine()}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pipeline", choices=["sitk"], help="run one SimpleITK registration (internal)")
    ap.add_argument("--fixed", type=Path)
    ap.add_argument("--moving", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--pairs", type=int, default=3, help="known rigid transforms")
    ap.add_argument("--rounds", type=int, default=3, help="runs of each pipeline on each pair")
    ap.add_argument("--remap", action="store_true", help="also each pair with remapped moving intensities")
    ap.add_argument("--keep", type=Path, help="keep the pairs and outputs in this folder")
    args = ap.parse_args()
    if args.pipeline == "sitk":
        run_sitk(args.fixed, args.moving, args.out)
        return

    binary = ROOT / "target/release/warpbench"
    if not binary.exists():
        sys.exit("build first: cargo build --release -p warpbench-app")
    tmp_obj = None
    if args.keep:
        tmp = args.keep
        tmp.mkdir(parents=True, exist_ok=True)
    else:
        tmp_obj = tempfile.TemporaryDirectory()
        tmp = Path(tmp_obj.name)
    pairs = make_pairs(tmp, args.pairs, args.remap)
    head = head_points()
    rows = []
    for k, pair in enumerate(pairs):
        cmds = {
            "warpbench": [str(binary), "align", "--fixed", str(FIXED), "--moving", str(pair["path"]), "--out-tfm",
                          str(tmp / f"wb_{k}.tfm"), "--json", "--quiet", "--force"],
            "sitk": [sys.executable, __file__, "--pipeline", "sitk", "--fixed", str(FIXED), "--moving",
                     str(pair["path"]), "--out", str(tmp / f"sitk_{k}.tfm")],
        }
        walls: dict[str, list[float]] = {name: [] for name in cmds}
        align_s: list[float] = []
        for _ in range(args.rounds):
            for name, cmd in cmds.items():
                start = time.perf_counter()
                run = subprocess.run(cmd, check=True, capture_output=True, text=True)
                walls[name].append(time.perf_counter() - start)
                if name == "warpbench":
                    align_s.append(json.loads(run.stdout)["align_s"])
        wb = errors(tmp / f"wb_{k}.tfm", pair["r"], pair["offset"], head)
        sk = errors(tmp / f"sitk_{k}.tfm", pair["r"], pair["offset"], head)
        ratio = statistics.median(b / a for a, b in zip(walls["warpbench"], walls["sitk"]))
        rows.append((pair["name"], statistics.median(walls["warpbench"]), statistics.median(walls["sitk"]), ratio,
                     wb, sk, statistics.median(align_s)))
        print(f"pair {pair['name']} done", file=sys.stderr, flush=True)

    print(f"\n{datetime.date.today()}, {machine()}; Colin27 1 mm as fixed, {args.rounds} rounds per pair, "
          "alternating, whole processes, medians")
    print("\n| pair | warpbench (s) | of which align_s | SimpleITK (s) | × | warpbench RMS mm / ° | SimpleITK RMS mm / ° |")
    print("|---|---|---|---|---|---|---|")
    for name, w, s, ratio, wb, sk, a in rows:
        print(f"| {name} | {w:.2f} | {a:.2f} | {s:.2f} | {ratio:.1f} | {wb[0]:.3f} / {wb[1]:.3f} | "
              f"{sk[0]:.3f} / {sk[1]:.3f} |")
    print(f"\nmedian ratio over pairs: {statistics.median(r[3] for r in rows):.1f}×; worst warpbench "
          f"{max(r[4][0] for r in rows):.3f} mm / {max(r[4][1] for r in rows):.3f}°, worst SimpleITK "
          f"{max(r[5][0] for r in rows):.3f} mm / {max(r[5][1] for r in rows):.3f}°")
    if tmp_obj:
        tmp_obj.cleanup()


if __name__ == "__main__":
    main()
