#!/usr/bin/env python3
"""Side by side, in one run: `warpbench register` and SimpleITK's B-spline registration (the set-up of SimpleITK's
`ImageRegistrationMethodBSpline3` example with Mattes mutual information), as whole processes, from the same 6-pair
affine start, on a head MRI under a known smooth warp against a second modality.

The case (seeded, made here with SimpleITK and numpy): Colin27 (tests/data/nifti/ch2.nii.gz, 1 mm) box-averaged by
`--shrink` (2 by default: 90×108×90 voxels of 2 mm; the example at 1 mm ran for more than 80 minutes on 2 cores) is
the T1. The known pull-back (fixed → moving) is u(x) = c + R (x − c) + Σₖ exp(−|x − cₖ|²/2σ²) wₖ: a rotation of
about 3° about the head's centre and six Gaussian bumps (σ 20 mm, |wₖ| from 3 to 7 mm, centred inside the head at
least 40 mm apart). The fixed image is the T1 through u (f(x) = T1(u(x)), linear), the moving image is the T1 with its
intensities remapped as a second modality's (v ↦ 1000 (1 − t)^1.5 + 50 t, t the normalised intensity: dark and
bright swap), each with its own noise of 2 % of its range. Six pairs (qᵢ in the head, at least 50 mm apart; pᵢ =
u(qᵢ)) are given; the affine start is their least-squares pull-back, written as an ITK `.tfm`. The TRE is measured
at 2 000 held-out points inside the head: |û(x) − u(x)|.

The two pipelines, each one whole process (start, read, register, write):

- `warpbench`: `warpbench register --fixed F --moving M --landmarks pairs.csv --initial affine.tfm --method affine
  --samples V --out-field D --json --quiet`, with V the fixed volume's voxel count: every voxel sampled, as the
  peer samples them (otherwise the defaults: 3 levels, 16 mm control spacing, landmark weight 1); one more run with
  the default sampling (at least 50 000 points and 10 per lattice coefficient a level) is reported beside it;
- `sitk`: this script with `--pipeline sitk`: the example's set-up, unchanged but for the metric the issue names:
  `BSplineTransformInitializer(fixed, [2, 2, 2])`, Mattes mutual information (50 bins, every voxel, the example sets
  no sampling), `GradientDescentLineSearch(5.0, 100, convergenceMinimumValue=1e-4, convergenceWindowSize=5)`, linear
  interpolation, `SetInitialTransformAsBSpline(scaleFactors=[1, 2, 5])`, shrink 4, 2, 1, smoothing σ 4, 2, 1; with
  the affine start as its moving initial transform, so the result is affine ∘ B-spline. It writes the composite
  transform.

The rounds alternate the pipelines; the table shows each pipeline's median wall time, the median of the per-round
ratios, and each result's mean TRE (read back from the files: warpbench's field through SimpleITK's
`DisplacementFieldTransform`, SimpleITK's composite transform directly), beside the identity's, the affine start's
warpbench's registration without the pairs (`--initial affine.tfm` alone, one run) and with its default sampling.

Run from the repository root after `cargo build --release -p warpbench-app`:

    data-cache/venv/bin/python data-scripts/compare_sitk_register.py [--rounds 3] [--shrink 2] [--keep DIR]

Versions measured: Python 3.11, numpy 2.4.6, SimpleITK 2.5.
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
SEED = 20261205


def head_mask_points(image, n: int, margin_mm: float, apart_mm: float, rng) -> np.ndarray:
    """n points where `image` is above a quarter of its range, `margin_mm` inside its box, `apart_mm` apart."""
    import SimpleITK as sitk

    a = sitk.GetArrayFromImage(image)
    lo, hi = float(a.min()), float(a.max())
    size = np.array(image.GetSize())
    first = np.array(image.TransformIndexToPhysicalPoint([0, 0, 0]))
    last = np.array(image.TransformIndexToPhysicalPoint([int(s - 1) for s in size]))
    box_lo, box_hi = np.minimum(first, last) + margin_mm, np.maximum(first, last) - margin_mm
    out: list[np.ndarray] = []
    while len(out) < n:
        x = rng.uniform(box_lo, box_hi)
        if any(np.linalg.norm(x - p) < apart_mm for p in out):
            continue
        index = image.TransformPhysicalPointToContinuousIndex(x.tolist())
        ijk = [int(round(c)) for c in index]
        if all(0 <= ijk[d] < size[d] for d in range(3)) and a[ijk[2], ijk[1], ijk[0]] > lo + 0.25 * (hi - lo):
            out.append(x)
    return np.array(out)


class Truth:
    """u(x) = c + R (x − c) + Σₖ exp(−|x − cₖ|²/2σ²) wₖ."""

    def __init__(self, centre: np.ndarray, centres: np.ndarray, vectors: np.ndarray, sigma: float = 20.0):
        a, b, g = 0.03, -0.02, 0.035
        rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
        rz = np.array([[np.cos(g), -np.sin(g), 0], [np.sin(g), np.cos(g), 0], [0, 0, 1]])
        self.r, self.c, self.centres, self.vectors, self.sigma = rz @ ry @ rx, centre, centres, vectors, sigma

    def __call__(self, x: np.ndarray) -> np.ndarray:
        y = self.c + (x - self.c) @ self.r.T
        for c, w in zip(self.centres, self.vectors):
            g = np.exp(-np.sum((x - c) ** 2, axis=-1) / (2 * self.sigma**2))
            y = y + g[..., None] * w
        return y


def make_case(tmp: Path, shrink: int) -> dict:
    import SimpleITK as sitk

    rng = np.random.default_rng(SEED)
    t1 = sitk.ReadImage(str(T1), sitk.sitkFloat32)
    if shrink > 1:
        t1 = sitk.BinShrink(t1, [shrink] * 3)
    size = np.array(t1.GetSize())
    centre = np.array(t1.TransformContinuousIndexToPhysicalPoint(((size - 1) / 2.0).tolist()))
    centres = head_mask_points(t1, 6, 40.0, 40.0, rng)
    vectors = rng.uniform(-1, 1, (6, 3))
    vectors *= (rng.uniform(3.0, 7.0, 6) / np.linalg.norm(vectors, axis=1))[:, None]
    truth = Truth(centre, centres, vectors)

    # f(x) = T1(u(x)): a displacement field u(x) − x on the T1's grid, applied by Resample.
    k, j, i = np.meshgrid(*[np.arange(n) for n in size[::-1]], indexing="ij")
    index = np.stack([i, j, k], axis=-1).reshape(-1, 3).astype(float)
    direction = np.array(t1.GetDirection()).reshape(3, 3)
    points = np.array(t1.GetOrigin()) + (index * np.array(t1.GetSpacing())) @ direction.T
    displacement = (truth(points) - points).reshape(*size[::-1], 3)
    field = sitk.GetImageFromArray(displacement, isVector=True)
    field.CopyInformation(t1)
    transform = sitk.DisplacementFieldTransform(sitk.Cast(field, sitk.sitkVectorFloat64))
    fixed = sitk.Resample(t1, t1, transform, sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    a = sitk.GetArrayFromImage(t1)
    lo, hi = float(a.min()), float(a.max())
    f = sitk.GetArrayFromImage(fixed)
    f = f + rng.normal(0, 0.02 * (hi - lo), f.shape)
    t = (a - lo) / (hi - lo)
    m = 1000.0 * (1.0 - t) ** 1.5 + 50.0 * t
    m = m + rng.normal(0, 0.02 * 1000.0, m.shape)
    fixed_image, moving_image = sitk.GetImageFromArray(f.astype(np.float32)), sitk.GetImageFromArray(m.astype(np.float32))
    fixed_image.CopyInformation(t1)
    moving_image.CopyInformation(t1)
    paths = {"fixed": tmp / "fixed.nii.gz", "moving": tmp / "moving.nii.gz"}
    sitk.WriteImage(fixed_image, str(paths["fixed"]))
    sitk.WriteImage(moving_image, str(paths["moving"]))

    qs = head_mask_points(fixed_image, 6, 30.0, 50.0, rng)
    ps = truth(qs)
    lines = [f'"Pt-{n}","true",' + ",".join(f'"{float(v)!r}"' for v in (*p, *q)) for n, (p, q) in enumerate(zip(ps, qs))]
    paths["pairs"] = tmp / "pairs.csv"
    paths["pairs"].write_text("\n".join(lines) + "\n")
    # The least-squares affine pull-back through the pairs: p ≈ A q + b.
    design = np.hstack([qs, np.ones((6, 1))])
    solution, *_ = np.linalg.lstsq(design, ps, rcond=None)
    affine = sitk.AffineTransform(3)
    affine.SetMatrix(solution[:3].T.flatten().tolist())
    affine.SetTranslation(solution[3].tolist())
    paths["affine"] = tmp / "affine.tfm"
    sitk.WriteTransform(affine, str(paths["affine"]))
    held_out = head_mask_points(fixed_image, 2000, 10.0, 0.0, rng)
    return {"paths": paths, "truth": truth, "held_out": held_out, "affine": affine, "size": size.tolist(),
            "spacing": list(t1.GetSpacing())}


def run_sitk(fixed_path: Path, moving_path: Path, initial: Path, out: Path) -> None:
    import SimpleITK as sitk

    fixed = sitk.ReadImage(str(fixed_path), sitk.sitkFloat32)
    moving = sitk.ReadImage(str(moving_path), sitk.sitkFloat32)
    start = sitk.ReadTransform(str(initial))
    tx = sitk.BSplineTransformInitializer(fixed, [2] * fixed.GetDimension())
    method = sitk.ImageRegistrationMethod()
    method.SetMetricAsMattesMutualInformation(numberOfHistogramBins=50)
    method.SetOptimizerAsGradientDescentLineSearch(5.0, 100, convergenceMinimumValue=1e-4, convergenceWindowSize=5)
    method.SetInterpolator(sitk.sitkLinear)
    method.SetMovingInitialTransform(start)
    method.SetInitialTransformAsBSpline(tx, inPlace=True, scaleFactors=[1, 2, 5])
    method.SetShrinkFactorsPerLevel([4, 2, 1])
    method.SetSmoothingSigmasPerLevel([4, 2, 1])
    result = method.Execute(fixed, moving)
    # Applied last-added first: the B-spline, then the affine start.
    sitk.WriteTransform(sitk.CompositeTransform([start, result]), str(out))


def mean_tre(transform, truth: Truth, points: np.ndarray) -> float:
    got = np.array([transform.TransformPoint(p.tolist()) for p in points])
    return float(np.mean(np.linalg.norm(got - truth(points), axis=1)))


def field_transform(path: Path):
    import SimpleITK as sitk

    return sitk.DisplacementFieldTransform(sitk.Cast(sitk.ReadImage(str(path)), sitk.sitkVectorFloat64))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pipeline", choices=["sitk"], help="run one SimpleITK registration (internal)")
    ap.add_argument("--fixed", type=Path)
    ap.add_argument("--moving", type=Path)
    ap.add_argument("--initial", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--rounds", type=int, default=3, help="runs of each pipeline")
    ap.add_argument("--shrink", type=int, default=2, help="box-average the 1 mm head by this factor")
    ap.add_argument("--keep", type=Path, help="keep the case and the outputs in this folder")
    args = ap.parse_args()
    if args.pipeline == "sitk":
        run_sitk(args.fixed, args.moving, args.initial, args.out)
        return

    import SimpleITK as sitk

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
    case = make_case(tmp, args.shrink)
    p = case["paths"]
    wb_field, sitk_tfm = tmp / "wb_field.nii.gz", tmp / "sitk.tfm"
    voxels = int(np.prod(case["size"]))
    register = [str(binary), "register", "--fixed", str(p["fixed"]), "--moving", str(p["moving"]), "--landmarks",
                str(p["pairs"]), "--initial", str(p["affine"]), "--method", "affine", "--quiet", "--force"]
    cmds = {
        "warpbench": [*register, "--samples", str(voxels), "--out-field", str(wb_field), "--json"],
        "sitk": [sys.executable, __file__, "--pipeline", "sitk", "--fixed", str(p["fixed"]), "--moving",
                 str(p["moving"]), "--initial", str(p["affine"]), "--out", str(sitk_tfm)],
    }
    walls: dict[str, list[float]] = {name: [] for name in cmds}
    register_s: list[float] = []
    for r in range(args.rounds):
        for name, cmd in cmds.items():
            start = time.perf_counter()
            run = subprocess.run(cmd, check=True, capture_output=True, text=True)
            walls[name].append(time.perf_counter() - start)
            if name == "warpbench":
                register_s.append(json.loads(run.stdout)["register_s"])
            print(f"round {r + 1}: {name} {walls[name][-1]:.1f} s", file=sys.stderr, flush=True)
    default_field = tmp / "wb_default.nii.gz"
    start = time.perf_counter()
    subprocess.run([*register, "--out-field", str(default_field)], check=True)
    default_s = time.perf_counter() - start
    alone_field = tmp / "wb_alone.nii.gz"
    subprocess.run([str(binary), "register", "--fixed", str(p["fixed"]), "--moving", str(p["moving"]), "--initial",
                    str(p["affine"]), "--samples", str(voxels), "--out-field", str(alone_field), "--quiet", "--force"],
                   check=True)

    truth, points = case["truth"], case["held_out"]
    identity = sitk.Transform(3, sitk.sitkIdentity)
    rows = [
        ("identity", mean_tre(identity, truth, points)),
        ("affine through the 6 pairs (the start)", mean_tre(case["affine"], truth, points)),
        ("warpbench, from the affine, without the pairs", mean_tre(field_transform(alone_field), truth, points)),
        ("warpbench register under the 6 pairs", mean_tre(field_transform(wb_field), truth, points)),
        (f"warpbench register under the 6 pairs, default sampling ({default_s:.1f} s, one run)",
         mean_tre(field_transform(default_field), truth, points)),
        ("SimpleITK BSpline3 (Mattes MI) from the affine", mean_tre(sitk.ReadTransform(str(sitk_tfm)), truth, points)),
    ]
    ratio = statistics.median(s / w for w, s in zip(walls["warpbench"], walls["sitk"]))
    size = "×".join(str(n) for n in case["size"])
    print(f"\n{datetime.date.today()}, {machine()}; Colin27 box-averaged by {args.shrink} ({size} voxels of "
          f"{case['spacing'][0]:.0f} mm), {args.rounds} rounds, alternating, whole processes, medians")
    print("\n| warp | mean TRE (mm) |\n|---|---|")
    for name, tre in rows:
        print(f"| {name} | {tre:.3f} |")
    print("\n| pipeline | wall time (s) | of which registering (s) |\n|---|---|---|")
    print(f"| warpbench register (every voxel) | {statistics.median(walls['warpbench']):.2f} | "
          f"{statistics.median(register_s):.2f} |")
    print(f"| SimpleITK BSpline3 (Mattes MI) | {statistics.median(walls['sitk']):.2f} | |")
    print(f"\nwarpbench is {ratio:.1f}× faster (median of the per-round ratios)")
    if tmp_obj:
        tmp_obj.cleanup()


if __name__ == "__main__":
    main()
