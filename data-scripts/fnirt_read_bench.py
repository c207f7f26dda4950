#!/usr/bin/env python3
"""Turning an FNIRT coefficient file into a deformation field: `warpbench field` against fslpy, whole processes in
turn (docs/benchmarks.md).

Makes, in a temporary folder, FNIRT's usual case at 1 mm: a reference of 182 x 218 x 182 voxels (MNI152's 1 mm grid,
radiological storage), an input of 176 x 256 x 256 (a T1), and cubic coefficients at FNIRT's default warp resolution
(knots every 10 reference voxels), seeded smooth values up to ~5 mm and a starting affine, written by fslpy's own
`toFnirt`. Then runs, RUNS times each and in turn (A B A B ...):

- A: `warpbench field --fixed REF --moving IN --field COEF --out a.nii.gz --quiet --force` (read, evaluate the
  spline at every reference voxel with the affine, write the pull-back as ITK's gzip NIfTI field);
- B: a Python that does the same with fslpy: `readFnirt`, `coefficientFieldToDeformationField` (relative, with the
  affine), saved as gzip NIfTI.

Prints the median wall seconds and CPU seconds (the child's own, `os.wait4`) of each, and the median of the A/B
ratios pair by pair.

Usage, from the repository root (the `.ci/run` venv, which has fslpy, and a release build):

    cargo build --release -p warpbench-app
    target/ci-python-venv/bin/python data-scripts/fnirt_read_bench.py [--runs 5] [--bin target/release/warpbench]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import nibabel as nib
import numpy as np
from fsl.data.image import Image
from fsl.transform import affine, fnirt, nonlinear

from process_timing import alternate, report

FSLPY = (
    "import sys, numpy as np; from fsl.data.image import Image; from fsl.transform import fnirt, nonlinear; "
    "c = fnirt.readFnirt(sys.argv[1], Image(sys.argv[3]), Image(sys.argv[2])); "
    "d = nonlinear.coefficientFieldToDeformationField(c, defType='relative', premat=True); "
    "d.save(sys.argv[4])"
)
REF = (182, 218, 182)
KNOTS = (10.0, 10.0, 10.0)


def make(folder: Path) -> tuple[Path, Path, Path]:
    def image(shape, aff, name):
        img = nib.Nifti1Image(np.zeros(shape, np.uint8), aff)
        img.set_sform(aff, 1)
        img.set_qform(aff, 1)
        path = folder / name
        img.to_filename(path)
        return path

    ref = image(REF, np.array([[-1, 0, 0, 90], [0, 1, 0, -126], [0, 0, 1, -72], [0, 0, 0, 1.0]]), "ref.nii.gz")
    src = image((176, 256, 256), np.array([[-1, 0, 0, 88], [0, 1, 0, -128], [0, 0, 1, -110], [0, 0, 0, 1.0]]),
                "in.nii.gz")
    rng = np.random.default_rng(20261207)
    shape = tuple(int(np.ceil(n / k)) + 3 for n, k in zip(REF, KNOTS)) + (3,)
    coefs = (rng.standard_normal(shape) * 2.0).astype(np.float32)
    premat = affine.compose([1.02, 0.98, 1.0], [2.0, -3.0, 1.0], [0.02, 0.0, -0.03], origin=[90, 109, 91])
    field = nonlinear.CoefficientField(nib.Nifti1Image(coefs, np.eye(4)), src=Image(str(src)), ref=Image(str(ref)),
                                       srcSpace="fsl", refSpace="fsl", fieldType="cubic", knotSpacing=KNOTS,
                                       fieldToRefMat=affine.scaleOffsetXform(KNOTS, 0), srcToRefMat=premat)
    out = fnirt.toFnirt(field)
    coef = folder / "coef.nii.gz"
    nib.Nifti1Image(out.data, None, out.header).to_filename(coef)
    return ref, src, coef


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--bin", default="target/release/warpbench")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ref, src, coef = make(Path(tmp))
        a_cmd = [args.bin, "field", "--fixed", str(ref), "--moving", str(src), "--field", str(coef),
                 "--out", str(Path(tmp) / "a.nii.gz"), "--quiet", "--force"]
        b_cmd = [sys.executable, "-c", FSLPY, str(coef), str(ref), str(src), str(Path(tmp) / "b.nii.gz")]
        a, b = alternate(a_cmd, b_cmd, args.runs)
        # The two outputs are one warp, compared through the input's points they take every 7th voxel to: fslpy's
        # relative field is in FSL mm (here the 1 mm voxels, both images radiological), warpbench's ITK field holds
        # RAS vectors in mm.
        fsl_field = np.asarray(nib.load(Path(tmp) / "b.nii.gz").dataobj)[::7, ::7, ::7].reshape(-1, 3)
        ours = np.asarray(nib.load(Path(tmp) / "a.nii.gz").dataobj)[::7, ::7, ::7].reshape(-1, 3)
        ijk = np.stack(np.meshgrid(*(np.arange(0, n, 7) for n in REF), indexing="ij"), -1).reshape(-1, 3)
        ref_aff, src_aff = nib.load(ref).affine, nib.load(src).affine
        theirs = (ijk + fsl_field) @ src_aff[:3, :3].T + src_aff[:3, 3]
        mine = ijk @ ref_aff[:3, :3].T + ref_aff[:3, 3] + ours
        print(f"largest difference between the two fields' points: {np.abs(theirs - mine).max():.2e} mm "
              f"(largest displacement {np.linalg.norm(ours, axis=1).max():.1f} mm)")
    report(a, b)


if __name__ == "__main__":
    main()
