#!/usr/bin/env python3
"""Side by side, in one run: `warpbench warp` (control texture and `--exact`), the SimpleITK field pipeline a user
would write, and ITK's exact thin-plate spline, all as whole processes on the same volume and landmarks.

The four pipelines, each one whole process (start, read, transform, resample, write a float32 `.nii`):

- `grid64`: `warpbench warp --grid 64 --interp linear --float --backend cpu` (the 64³ control texture);
- `exact`: the same with `--exact` (the TPS evaluated at every voxel);
- `sitk_field`: SimpleITK: read, the TPS fitted in numpy (U(r) = r, stiffness 0, fixed points → moving points) and
  evaluated on a 64³ grid over the output box, `sitk.DisplacementFieldTransform` (linear in the field) +
  `sitk.Resample` (linear, default 0, float32), write (this script run with `--pipeline sitk_field`);
- `itk_tps`: ITK: read, `itk.ThinPlateSplineKernelTransform[itk.D, 3]` (source landmarks = fixed points q_i, target
  landmarks = moving points p_i: the pull-back that `ResampleImageFilter` wants) + `itk.ResampleImageFilter` (linear,
  default 0), write (`--pipeline itk_tps`).

The rounds alternate the pipelines (A B C D, A B C D, ...); the table shows each pipeline's median wall time over
the rounds, warpbench's own phase times (`seconds` of `warp --json`, medians), and for each warpbench pipeline the
median of its per-round ratios to each peer. It ends with the voxel differences between the outputs and ITK's exact
TPS (max and 99.99th percentile, in the volume's intensity units), and the machine and date.

The volume: `--volume PATH` (any NIfTI, e.g. a real head MRI), or by default a head MRI of `--shape` (176,256,256)
int16 `.nii.gz` made from the Colin27 fixture (tests/data/nifti/ch2.nii.gz): trilinear onto the shape over its own
box, intensities ×4, plus seeded Gaussian noise σ = 6, so that gzip compresses it no better than a scanner's file
(12.7 MB, against about 8 MB for a real head MRI of that shape: a little more to inflate). The landmarks are N seeded fixed points in the central 80 % of the box and moving points displaced by
a smooth 5 mm field.

Run from the repository root after `cargo build --release -p warpbench-app`:

    data-cache/venv/bin/python data-scripts/compare_itk_warp.py [--n 100] [--rounds 5] [--keep DIR]

Versions measured: Python 3, nibabel 5.4.2, numpy 2.4.6, SimpleITK 2.5.7, itk 5.4.7.
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

import nibabel as nib
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SEED = 20261122
GRID = 64


def _trilinear(a: np.ndarray, coords: list[np.ndarray]) -> np.ndarray:
    """a sampled at the outer product of the per-axis continuous indices `coords` (edge-clamped), axis by axis."""
    for axis, c in enumerate(coords):
        i0 = np.clip(np.floor(c).astype(int), 0, a.shape[axis] - 1)
        i1 = np.minimum(i0 + 1, a.shape[axis] - 1)
        f = (c - i0).reshape([-1 if d == axis else 1 for d in range(3)]).astype(np.float32)
        a = np.take(a, i0, axis=axis) * (1 - f) + np.take(a, i1, axis=axis) * f
    return a


def make_head(shape: tuple[int, int, int], out: Path) -> nib.Nifti1Image:
    img = nib.load(ROOT / "tests/data/nifti/ch2.nii.gz")
    a = np.asanyarray(img.dataobj).astype(np.float32)
    coords = [np.linspace(0, a.shape[d] - 1, shape[d]) for d in range(3)]
    b = _trilinear(a, coords) * 4.0
    b += np.random.default_rng(SEED).normal(0.0, 6.0, size=b.shape).astype(np.float32)
    b = np.clip(np.rint(b), 0, 32767).astype(np.int16)
    scale = [(a.shape[d] - 1) / (shape[d] - 1) for d in range(3)]
    aff = img.affine @ np.diag([*scale, 1.0])
    vol = nib.Nifti1Image(b, aff)
    vol.set_sform(aff, 1)
    vol.set_qform(aff, 1)
    vol.header.set_slope_inter(1.0, 0.0)
    nib.save(vol, out)
    return vol


def landmarks(vol: nib.Nifti1Image, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed and moving points in LPS mm (NIfTI affines are RAS: flip x and y)."""
    rng = np.random.default_rng(SEED)
    shape = np.array(vol.shape[:3])
    ijk = rng.uniform(0.1, 0.9, size=(n, 3)) * (shape - 1)
    ras = (vol.affine @ np.c_[ijk, np.ones(n)].T).T[:, :3]
    q = ras * np.array([-1.0, -1.0, 1.0])
    disp = 5.0 * np.stack([np.sin(q[:, 1] / 25.0), np.sin(q[:, 2] / 30.0), np.cos(q[:, 0] / 28.0)], axis=1)
    return q, q + disp


def write_csv(path: Path, q: np.ndarray, p: np.ndarray) -> None:
    with path.open("w") as f:
        for i, (pi, qi) in enumerate(zip(p, q)):
            fields = ",".join(f'"{v:.6f}"' for v in [*pi, *qi])
            f.write(f'"Pt-{i}","true",{fields}\n')


def read_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [[float(v.strip('"')) for v in line.strip().split(",")[2:]] for line in path.open() if line.strip()]
    pq = np.array(rows)
    return pq[:, 3:], pq[:, :3]


# --- The peers, each run as its own process (`--pipeline NAME`) ---------------------------------------------------


def tps_fit(q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The interpolating 3-D TPS u(x) = Σ wᵢ ‖x − qᵢ‖ + A [x; 1] with u(qᵢ) = pᵢ (U(r) = r, as ITK's)."""
    n = len(q)
    k = np.linalg.norm(q[:, None, :] - q[None, :, :], axis=2)
    pm = np.c_[q, np.ones(n)]
    lhs = np.zeros((n + 4, n + 4))
    lhs[:n, :n], lhs[:n, n:], lhs[n:, :n] = k, pm, pm.T
    sol = np.linalg.solve(lhs, np.r_[p, np.zeros((4, 3))])
    return sol[:n], sol[n:]


def tps_displacement(q: np.ndarray, w: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """u(x) − x at the points x (m × 3), a block of points at a time."""
    out = np.empty_like(x)
    for s in range(0, len(x), 16384):
        xs = x[s:s + 16384]
        r = np.sqrt(((xs[:, None, :] - q[None, :, :]) ** 2).sum(axis=2))
        out[s:s + 16384] = r @ w + np.c_[xs, np.ones(len(xs))] @ a - xs
    return out


def run_sitk_field(vol: Path, csv: Path, out: Path) -> None:
    import SimpleITK as sitk

    image = sitk.ReadImage(str(vol), sitk.sitkFloat32)
    q, p = read_csv(csv)
    w, a = tps_fit(q, p)
    # A GRID³ field over the image's box (corner voxel centres to corner voxel centres), in LPS as SimpleITK is.
    size = np.array(image.GetSize())
    spacing = np.array(image.GetSpacing()) * (size - 1) / (GRID - 1)
    direction = np.array(image.GetDirection()).reshape(3, 3)
    origin = np.array(image.GetOrigin())
    ijk = np.stack(np.meshgrid(*[np.arange(GRID)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    x = origin + (ijk * spacing) @ direction.T
    d = tps_displacement(q, w, a, x).reshape(GRID, GRID, GRID, 3)
    field = sitk.GetImageFromArray(np.ascontiguousarray(d.transpose(2, 1, 0, 3)), isVector=True)
    field.SetOrigin(tuple(origin))
    field.SetSpacing(tuple(spacing))
    field.SetDirection(tuple(direction.ravel()))
    transform = sitk.DisplacementFieldTransform(sitk.Cast(field, sitk.sitkVectorFloat64))
    warped = sitk.Resample(image, image, transform, sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    sitk.WriteImage(warped, str(out))


def run_itk_tps(vol: Path, csv: Path, out: Path) -> None:
    import itk

    image = itk.imread(str(vol), itk.F)
    q, p = read_csv(csv)
    transform = itk.ThinPlateSplineKernelTransform[itk.D, 3].New()
    point_set = type(transform.GetSourceLandmarks())
    source, target = point_set.New(), point_set.New()
    for i, (qi, pi) in enumerate(zip(q, p)):
        source.SetPoint(i, [float(v) for v in qi])
        target.SetPoint(i, [float(v) for v in pi])
    transform.SetSourceLandmarks(source)
    transform.SetTargetLandmarks(target)
    transform.ComputeWMatrix()
    resample = itk.ResampleImageFilter[type(image), type(image)].New()
    resample.SetInput(image)
    resample.SetReferenceImage(image)
    resample.UseReferenceImageOn()
    resample.SetTransform(transform)
    resample.SetInterpolator(itk.LinearInterpolateImageFunction[type(image), itk.D].New())
    resample.SetDefaultPixelValue(0.0)
    resample.Update()
    itk.imwrite(resample.GetOutput(), str(out))


# --- The run ------------------------------------------------------------------------------------------------------


def commands(binary: Path, vol: Path, csv: Path, tmp: Path) -> dict[str, list[str]]:
    warp = [str(binary), "warp", "--fixed", str(vol), "--moving", str(vol), "--landmarks", str(csv), "--interp",
            "linear", "--float", "--backend", "cpu", "--quiet", "--json", "--force"]
    me = [sys.executable, str(Path(__file__).resolve()), "--volume", str(vol), "--landmarks", str(csv)]
    return {
        "grid64": [*warp, "--grid", str(GRID), "--out", str(tmp / "grid64.nii")],
        "exact": [*warp, "--exact", "--out", str(tmp / "exact.nii")],
        "sitk_field": [*me, "--pipeline", "sitk_field", "--out", str(tmp / "sitk_field.nii")],
        "itk_tps": [*me, "--pipeline", "itk_tps", "--out", str(tmp / "itk_tps.nii")],
    }


def machine() -> str:
    model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                  if line.startswith("model name")), platform.processor())
    return f"{os.cpu_count()} cores, {model}, {platform.system()} {platform.machine()}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--volume", type=Path, help="the volume (fixed and moving); default: a head MRI made here")
    ap.add_argument("--shape", default="176,256,256", help="the made volume's shape")
    ap.add_argument("--landmarks", type=Path, help="with --pipeline: the landmark CSV")
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--binary", type=Path, default=ROOT / "target/release/warpbench")
    ap.add_argument("--rounds", type=int, default=5, help="rounds of the alternating pipelines")
    ap.add_argument("--only", default="grid64,exact,sitk_field,itk_tps", help="the pipelines to run, by name")
    ap.add_argument("--keep", type=Path, help="write the volume, landmarks and outputs here and keep them")
    ap.add_argument("--pipeline", choices=["sitk_field", "itk_tps"], help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.pipeline:
        {"sitk_field": run_sitk_field, "itk_tps": run_itk_tps}[args.pipeline](args.volume, args.landmarks, args.out)
        return

    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.keep or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        if args.volume:
            vol_path, vol = args.volume, nib.load(args.volume)
        else:
            vol_path = tmp / "head.nii.gz"
            shape = tuple(int(s) for s in args.shape.split(","))
            vol = make_head(shape, vol_path) if not vol_path.exists() else nib.load(vol_path)
        q, p = landmarks(vol, args.n)
        csv = tmp / "pairs.csv"
        write_csv(csv, q, p)
        cmds = {k: v for k, v in commands(args.binary, vol_path, csv, tmp).items() if k in args.only.split(",")}
        walls: dict[str, list[float]] = {k: [] for k in cmds}
        phases: dict[str, list[dict]] = {k: [] for k in cmds}
        for _ in range(args.rounds):
            for name, cmd in cmds.items():
                start = time.perf_counter()
                run = subprocess.run(cmd, check=True, capture_output=True, text=True)
                walls[name].append(time.perf_counter() - start)
                if name in ("grid64", "exact"):
                    phases[name].append(json.loads(run.stdout)["seconds"])

        print(f"# {vol_path.name}: {vol.shape[:3]} {vol.get_data_dtype()}, {vol_path.stat().st_size / 1e6:.1f} MB; "
              f"N = {args.n}, TPS, linear, float32 .nii out; {args.rounds} rounds, alternating, medians")
        print(f"# machine: {machine()}; {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC")
        print("\n| pipeline | median (s) | warpbench phases (s) |")
        print("|---|---|---|")
        for name in cmds:
            ph = ""
            if phases[name]:
                keys = phases[name][0].keys()
                ph = ", ".join(f"{k} {statistics.median(r[k] for r in phases[name]):.3f}" for k in keys)
            print(f"| {name} | {statistics.median(walls[name]):.3f} | {ph} |")
        print("\n| ratio (median of per-round ratios) | × |")
        print("|---|---|")
        for ours in ("grid64", "exact"):
            for peer in ("sitk_field", "itk_tps"):
                if ours in cmds and peer in cmds:
                    r = statistics.median(b / a for a, b in zip(walls[ours], walls[peer]))
                    print(f"| {peer} / {ours} | {r:.1f} |")
        if "itk_tps" in cmds:
            ref = np.asanyarray(nib.load(tmp / "itk_tps.nii").dataobj).astype(np.float32)
            print("\n| output against itk_tps | max abs diff | 99.99th pct | voxels > 1 |")
            print("|---|---|---|---|")
            for name in cmds:
                if name != "itk_tps":
                    d = np.abs(np.asanyarray(nib.load(tmp / f"{name}.nii").dataobj).astype(np.float32) - ref)
                    print(f"| {name} | {d.max():.4f} | {np.quantile(d, 0.9999):.4f} | {int((d > 1).sum())} |")


if __name__ == "__main__":
    main()
