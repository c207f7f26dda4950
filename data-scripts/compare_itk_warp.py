#!/usr/bin/env python3
"""Side by side: ITK's thin-plate-spline resampling and `warpbench warp`, on the same volume and landmarks, in one run.

ITK: `itk.ThinPlateSplineKernelTransform[itk.D, 3]` (kernel U(r) = r, stiffness 0) with source landmarks = the fixed
points q_i and target landmarks = the moving points p_i, so the transform maps an output (fixed) point to the input
(moving) point, as ResampleImageFilter wants; `itk.ResampleImageFilter` with linear interpolation and default value 0
onto the volume's own grid. warpbench: `warpbench warp --exact --interp linear --float` (exact TPS per voxel, the same
math) and the default `--grid 64` control texture, both on the CPU (rayon).

The volume is the Colin27 MRI fixture (tests/data/nifti/ch2.nii.gz) resampled (nearest) to SIZE³ on its own box,
float32. The landmarks are N seeded fixed points in the central 80 % of the box, and moving points displaced by a
smooth 5 mm field. Prints a JSON report: ITK's resampling time (Update() only, the image already in memory), the
warpbench command's wall time (load, fit, resample, write: everything), their ratio, and the voxel differences
between the exports (max and 99.99th percentile, in intensity units of the 0..255 MRI).

Run from the repository root after `cargo build --release`:

    data-cache/venv/bin/python data-scripts/compare_itk_warp.py [--size 256] [--n 100]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import nibabel as nib
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SEED = 20261122


def make_volume(size: int, out: Path) -> nib.Nifti1Image:
    img = nib.load(ROOT / "tests/data/nifti/ch2.nii.gz")
    a = np.asanyarray(img.dataobj).astype(np.float32)
    idx = [np.minimum((np.arange(size) * a.shape[d] / size).astype(int), a.shape[d] - 1) for d in range(3)]
    b = a[idx[0]][:, idx[1]][:, :, idx[2]]
    aff = img.affine @ np.diag([a.shape[0] / size, a.shape[1] / size, a.shape[2] / size, 1.0])
    vol = nib.Nifti1Image(b, aff)
    vol.set_sform(aff, 1)
    vol.set_qform(aff, 1)
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


def itk_resample(path: Path, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, float]:
    import itk

    image = itk.imread(str(path), itk.F)
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
    start = time.perf_counter()
    resample.Update()
    seconds = time.perf_counter() - start
    # itk arrays are [z, y, x]; nibabel's are [x, y, z].
    return np.transpose(itk.array_from_image(resample.GetOutput()), (2, 1, 0)), seconds


def warpbench(binary: Path, vol: Path, csv: Path, out: Path, extra: list[str]) -> tuple[np.ndarray, float]:
    cmd = [str(binary), "warp", "--fixed", str(vol), "--moving", str(vol), "--landmarks", str(csv), "--interp",
           "linear", "--float", "--backend", "cpu", "--quiet", "--force", "--out", str(out), *extra]
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    seconds = time.perf_counter() - start
    return np.asanyarray(nib.load(out).dataobj).astype(np.float32), seconds


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--binary", type=Path, default=ROOT / "target/release/warpbench")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        vol_path = tmp / "volume.nii"
        vol = make_volume(args.size, vol_path)
        q, p = landmarks(vol, args.n)
        csv = tmp / "pairs.csv"
        write_csv(csv, q, p)
        itk_out, itk_s = itk_resample(vol_path, q, p)
        report = {"size": args.size, "landmarks": args.n, "itk_seconds": round(itk_s, 3)}
        for name, extra in [("exact", ["--exact"]), ("grid64", ["--grid", "64"])]:
            ours, s = warpbench(args.binary, vol_path, csv, tmp / f"{name}.nii", extra)
            diff = np.abs(ours - itk_out)
            report[name] = {
                "warpbench_seconds": round(s, 3),
                "speedup_vs_itk": round(itk_s / s, 2),
                "max_abs_diff": float(diff.max()),
                "p9999_abs_diff": float(np.quantile(diff, 0.9999)),
                "voxels_over_1": int((diff > 1.0).sum()),
            }
        print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
