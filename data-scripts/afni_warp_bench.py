#!/usr/bin/env python3
"""Turning an AFNI 3dQwarp warp into ITK's displacement field: `warpbench field` against nitransforms, whole
processes in turn (docs/benchmarks.md).

Makes, in a temporary folder, a warp the size of one on AFNI's MNI template at 1 mm (193 x 229 x 193 voxels, RAI, as
`MNI152_2009_template_SSW.nii.gz`): seeded smooth displacements up to ~6 mm saved as AFNI saves `3dQwarp -prefix
anat_WARP.nii.gz` (an (X, Y, Z, 1, 3) float32 array, AFNI's extension labelling the sub-brick `x_delta`, `y_delta`,
`z_delta`, gzip), and the template's grid as a volume. Then runs, RUNS times each and in turn (A B A B ...):

- A: `warpbench field --fixed BASE --moving BASE --field anat_WARP.nii.gz --out a.nii.gz --quiet --force` (read the
  warp, sample it on the base's grid, write ITK's gzip NIfTI field);
- B: a Python that does the same with nitransforms: `DenseFieldTransform.from_filename(W, fmt="afni")`, then
  `to_filename(b.nii.gz, fmt="itk")`.

Prints the median wall and CPU seconds of each and the median of the A/B ratios pair by pair, and how far apart the
two fields' points are.

Usage, from the repository root (the `.ci/run` venv, which has nitransforms, and a release build):

    cargo build --release -p warpbench-app
    target/ci-python-venv/bin/python data-scripts/afni_warp_bench.py [--runs 5] [--bin target/release/warpbench]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import nibabel as nib
import numpy as np

from process_timing import alternate, report

NITRANSFORMS = (
    "import sys; from nitransforms.nonlinear import DenseFieldTransform as D; "
    "D.from_filename(sys.argv[1], fmt='afni').to_filename(sys.argv[2], fmt='itk')"
)
SHAPE = (193, 229, 193)
# The RAI grid of AFNI's MNI152_2009 template: x from right to left, y from front to back (LPS origin, RAS affine).
AFFINE = np.array([[-1.0, 0, 0, 96.0], [0, -1.0, 0, 132.0], [0, 0, 1.0, -78.0], [0, 0, 0, 1.0]])
NIML = (
    "<?xml version='1.0' ?>\n<AFNI_attributes\n  self_idcode=\"AFN_warpbench_bench\"\n  ni_form=\"ni_group\" >\n"
    "<AFNI_atr\n  ni_type=\"String\"\n  ni_dimen=\"1\"\n  atr_name=\"BRICK_LABS\" >\n \"x_delta~y_delta~z_delta\"\n"
    "</AFNI_atr>\n</AFNI_attributes>\n"
)


def make(folder: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(20261207)
    grids = np.meshgrid(*(np.linspace(0.0, 1.0, n, dtype=np.float32) for n in SHAPE), indexing="ij", sparse=True)
    field = np.zeros((*SHAPE, 1, 3), np.float32)
    for c in range(3):
        for _ in range(2):
            a, f, p = rng.uniform(1.0, 3.0), rng.uniform(0.5, 1.5, 3), rng.uniform(0, 2 * np.pi, 3)
            terms = [np.sin(np.float32(np.pi * f[d]) * grids[d] + np.float32(p[d])) for d in range(3)]
            field[..., 0, c] += np.float32(a) * terms[0] * terms[1] * terms[2]
    warp = nib.Nifti1Image(field, AFFINE)
    warp.header.set_sform(AFFINE, code=4)
    warp.header.set_qform(AFFINE, code=4)
    warp.header.extensions.append(nib.nifti1.Nifti1Extension(4, NIML.encode() + b"\0"))
    base = nib.Nifti1Image(np.zeros(SHAPE, np.uint8), AFFINE)
    base.set_sform(AFFINE, 4)
    base.set_qform(AFFINE, 4)
    paths = folder / "anat_WARP.nii.gz", folder / "base.nii.gz"
    warp.to_filename(paths[0])
    base.to_filename(paths[1])
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--bin", default="target/release/warpbench")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        warp, base = make(Path(tmp))
        a_out, b_out = Path(tmp) / "a.nii.gz", Path(tmp) / "b.nii.gz"
        a_cmd = [args.bin, "field", "--fixed", str(base), "--moving", str(base), "--field", str(warp),
                 "--out", str(a_out), "--quiet", "--force"]
        b_cmd = [sys.executable, "-c", NITRANSFORMS, str(warp), str(b_out)]
        a, b = alternate(a_cmd, b_cmd, args.runs)
        # Both are ITK fields of one warp; nitransforms writes intent 1007 (ANTs' LPS vectors), warpbench 1006 (RAS):
        # compared as the LPS vectors each means, every 5th voxel.
        ours = np.asarray(nib.load(a_out).dataobj)[::5, ::5, ::5].reshape(-1, 3) * [-1.0, -1.0, 1.0]
        theirs_img = nib.load(b_out)
        theirs = np.asarray(theirs_img.dataobj)[::5, ::5, ::5].reshape(-1, 3)
        if int(theirs_img.header["intent_code"]) == 1006:
            theirs = theirs * [-1.0, -1.0, 1.0]
        print(f"nitransforms' field: intent {int(theirs_img.header['intent_code'])}; largest difference from "
              f"warpbench's: {np.abs(ours - theirs).max():.2e} mm (largest displacement "
              f"{np.linalg.norm(ours, axis=1).max():.1f} mm)")
    report(a, b)


if __name__ == "__main__":
    main()
