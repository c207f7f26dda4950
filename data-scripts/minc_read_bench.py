#!/usr/bin/env python3
"""Reading a MINC 2 volume: `warpbench info` against nibabel, whole processes in turn (docs/benchmarks.md).

Writes a 256^3 int16 MINC 2 file into a temporary folder (SimpleITK 2.5.7 writes it, h5py stores the image again in
deflated chunks of 32 x 64 x 64; seeded normal values, so it barely compresses; identity scaling), then runs, RUNS
times each and in turn (A B A B ...): A = `warpbench info FILE --quiet`, B = a Python that loads it with nibabel to
float32 (`np.asarray(nib.load(FILE).get_fdata(dtype=np.float32))`). Prints the median wall seconds and CPU seconds (the
child's own accounting, `os.wait4`) of each, and the median of the A/B ratios taken pair by pair. (Peak memory is not
printed: a child's `ru_maxrss` starts from the forking Python's.)

Usage, from the repository root (the `.ci/run` venv and a release build):

    cargo build --release -p warpbench-app
    target/ci-python-venv/bin/python data-scripts/minc_read_bench.py [--runs 7] [--bin target/release/warpbench]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np
import SimpleITK as sitk

from process_timing import alternate, report

NIBABEL_LOAD = (
    "import sys, numpy as np, nibabel as nib; "
    "d = np.asarray(nib.load(sys.argv[1]).get_fdata(dtype=np.float32)); print(d.shape)"
)


def make(folder: Path) -> Path:
    plain, chunked = folder / "plain.mnc", folder / "chunked.mnc"
    values = (np.random.default_rng(0).normal(size=(256, 256, 256)) * 300).astype(np.int16)
    sitk.WriteImage(sitk.GetImageFromArray(values), str(plain))
    with h5py.File(plain, "r") as f, h5py.File(chunked, "w") as g:
        f.copy("minc-2.0", g)
        del g["minc-2.0/image/0/image"]
        src = f["minc-2.0/image/0/image"]
        d = g.create_dataset("minc-2.0/image/0/image", data=src[()], chunks=(32, 64, 64), compression="gzip",
                             compression_opts=4)
        for k, v in src.attrs.items():
            d.attrs[k] = v
    return chunked


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--bin", default="target/release/warpbench")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = make(Path(tmp))
        a_cmd = [args.bin, "info", str(path), "--quiet"]
        b_cmd = [sys.executable, "-c", NIBABEL_LOAD, str(path)]
        a, b = alternate(a_cmd, b_cmd, args.runs)
    report(a, b)


if __name__ == "__main__":
    main()
