#!/usr/bin/env python3
"""Side by side: ITK's thin-plate-spline resampling and `warpbench warp`, on the same volume and landmarks, in one run.

ITK: `itk.ThinPlateSplineKernelTransform[itk.D, 3]` (kernel U(r) = r, stiffness 0) with source landmarks = the fixed
points q_i and target landmarks = the moving points p_i, so the transform maps an output (fixed) point to the input
(moving) point, as ResampleImageFilter wants; `itk.ResampleImageFilter` with linear interpolation and default value 0
onto the volume's own grid. warpbench: `warpbench warp --exact --interp linear --float` (exact TPS per voxel, the same
math) and the default `--grid 64` control texture, both on the CPU (rayon).

The volume is the Colin27 MRI fixture (tests/data/nifti/ch2.nii.gz) resampled (nearest) to SIZE³ on its own box,
float32. The landmarks are N seeded fixed points in the central 80 % of the box, and moving points displaced by a
smooth 5 mm field. Prints a JSON report, each time the best of --repeats runs on both sides:

- like for like, the resampling alone: ITK's `Update()` (a new filter each run, the image already in memory) against
  warpbench's own resampling time (`seconds.resample` of `warp --json`: the export, output allocation included);
- end to end: ITK's whole pipeline (read, transform set-up, resample, write; its first run) against the whole
  `warpbench warp` command (process start, load, fit, resample, atomic write with fsync);
- the voxel differences between the exports (max and 99.99th percentile, in intensity units of the 0..255 MRI).

Run from the repository root after `cargo build --release`:

    data-cache/venv/bin/python data-scripts/compare_itk_warp.py [--size 256] [--n 100] [--repeats 3] [--keep DIR]
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


def itk_resample(path: Path, q: np.ndarray, p: np.ndarray, repeats: int, out: Path) -> tuple[np.ndarray, dict]:
    """ITK's resampling: the best of `repeats` Update() calls (a new filter each time, the image already in memory),
    and one whole pipeline (read, transform set-up, resample, write) timed end to end."""
    import itk

    pipeline_start = time.perf_counter()
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
    updates = []
    for _ in range(repeats):
        resample = itk.ResampleImageFilter[type(image), type(image)].New()
        resample.SetInput(image)
        resample.SetReferenceImage(image)
        resample.UseReferenceImageOn()
        resample.SetTransform(transform)
        resample.SetInterpolator(itk.LinearInterpolateImageFunction[type(image), itk.D].New())
        resample.SetDefaultPixelValue(0.0)
        start = time.perf_counter()
        resample.Update()
        updates.append(time.perf_counter() - start)
        if len(updates) == 1:
            itk.imwrite(resample.GetOutput(), str(out))
            pipeline = time.perf_counter() - pipeline_start
    # itk arrays are [z, y, x]; nibabel's are [x, y, z].
    result = np.transpose(itk.array_from_image(resample.GetOutput()), (2, 1, 0))
    return result, {"resample_seconds": round(min(updates), 3), "pipeline_seconds": round(pipeline, 3),
                    "threads": itk.MultiThreaderBase.GetGlobalDefaultNumberOfThreads()}


def warpbench(binary: Path, vol: Path, csv: Path, out: Path, extra: list[str], repeats: int) -> tuple[np.ndarray, dict]:
    """The best of `repeats` runs of `warpbench warp`: its wall time (everything: load, fit, resample, write) and its
    own resampling time (`seconds.resample` of its JSON report: the export, output allocation included)."""
    cmd = [str(binary), "warp", "--fixed", str(vol), "--moving", str(vol), "--landmarks", str(csv), "--interp",
           "linear", "--float", "--backend", "cpu", "--quiet", "--json", "--force", "--out", str(out), *extra]
    walls, resamples = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        report = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
        walls.append(time.perf_counter() - start)
        resamples.append(report["seconds"]["resample"])
    data = np.asanyarray(nib.load(out).dataobj).astype(np.float32)
    return data, {"resample_seconds": round(min(resamples), 3), "command_seconds": round(min(walls), 3)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--binary", type=Path, default=ROOT / "target/release/warpbench")
    ap.add_argument("--repeats", type=int, default=3, help="best of this many runs, on both sides")
    ap.add_argument("--keep", type=Path, help="write the volume, landmarks and outputs here and keep them")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.keep or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        vol_path = tmp / "volume.nii"
        vol = make_volume(args.size, vol_path)
        q, p = landmarks(vol, args.n)
        csv = tmp / "pairs.csv"
        write_csv(csv, q, p)
        itk_out, itk = itk_resample(vol_path, q, p, args.repeats, tmp / "itk.nii")
        report = {"size": args.size, "landmarks": args.n, "repeats": args.repeats, "itk": itk}
        for name, extra in [("exact", ["--exact"]), ("grid64", ["--grid", "64"])]:
            ours, t = warpbench(args.binary, vol_path, csv, tmp / f"{name}.nii", extra, args.repeats)
            diff = np.abs(ours - itk_out)
            report[name] = {
                **t,
                "resample_speedup_vs_itk": round(itk["resample_seconds"] / t["resample_seconds"], 1),
                "command_speedup_vs_itk_pipeline": round(itk["pipeline_seconds"] / t["command_seconds"], 1),
                "max_abs_diff": float(diff.max()),
                "p9999_abs_diff": float(np.quantile(diff, 0.9999)),
                "voxels_over_1": int((diff > 1.0).sum()),
            }
        print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
