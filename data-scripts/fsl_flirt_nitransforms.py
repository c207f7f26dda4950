#!/usr/bin/env python3
"""FSL's FLIRT matrices between small volumes of either handedness, written and read by nitransforms.

A FLIRT matrix (`flirt -omat`) maps the input image's FSL coordinates to the reference image's, so it means nothing
without the two images. nitransforms 25.1.0 (`nitransforms.io.fsl`, which its authors check against FSL's tools) is
the independent writer and reader. Writes into tests/data/fsl/ (deterministic but for gzip's timestamp):

- `oblique.nii.gz` (an oblique grid, voxel-to-RAS determinant > 0: FSL reverses its first axis),
  `las.nii.gz` (radiological, determinant < 0), `lps.nii.gz` (determinant > 0) and `oblique_las.nii.gz`
  (oblique, determinant < 0): 4 x 5 x 3 float32 volumes of nibabel 5.4.2, only their grids matter;
- `oblique_from_las.mat`: nitransforms' FSL writing of a known RAS transform T (reference points to moving points)
  with `oblique.nii.gz` as the reference and `las.nii.gz` as the moving image; `lps_from_oblique_las.mat` likewise
  for the other two;
- `reference.json`: for each matrix, the RAS matrix nitransforms reads from the file with the same two images
  (`nitransforms.linear.load(path, fmt="fsl", reference=..., moving=...).matrix`), the pull-back warpbench must
  read, and T itself.

Usage, from the repository root (a Python with nitransforms 25.1.0, scipy, h5py, nibabel 5.4.2 and numpy 2.4.6,
e.g. the venv `.ci/run` makes):

    target/ci-python-venv/bin/python data-scripts/fsl_flirt_nitransforms.py
"""

from __future__ import annotations

import json
from pathlib import Path

import nibabel as nib
import nitransforms
import nitransforms.linear as nitl
import numpy as np
from fixture_grids import affine, rotation

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "fsl"


GRIDS = {
    "oblique": (rotation(0.1, -0.2, 0.3) @ np.diag([1.2, 0.9, 2.0]), (-30.0, 20.0, 10.0)),
    "las": (np.diag([-1.5, 1.0, 1.1]), (40.0, -25.0, -15.0)),
    "lps": (np.diag([-2.0, -2.0, 2.5]), (20.0, 18.0, -12.0)),
    "oblique_las": (rotation(-0.15, 0.05, 0.2) @ np.diag([-1.0, 1.3, 1.6]), (12.0, -30.0, 5.0)),
}
PAIRS = {"oblique_from_las": ("oblique", "las"), "lps_from_oblique_las": ("lps", "oblique_las")}


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, (linear, origin) in GRIDS.items():
        data = np.arange(60, dtype=np.float32).reshape(4, 5, 3)
        nib.save(nib.Nifti1Image(data, affine(linear, origin)), OUT / f"{name}.nii.gz")
    t = affine(rotation(0.2, 0.1, -0.15) @ np.diag([1.05, 0.97, 1.02]), [3.0, -2.0, 5.0])
    reference = {"nitransforms": nitransforms.__version__, "nibabel": nib.__version__, "known_ras": t.tolist()}
    for mat, (fixed, moving) in PAIRS.items():
        f, m = str(OUT / f"{fixed}.nii.gz"), str(OUT / f"{moving}.nii.gz")
        path = OUT / f"{mat}.mat"
        nitl.Affine(t, reference=f).to_filename(path, fmt="fsl", moving=m)
        read = nitl.load(path, fmt="fsl", reference=f, moving=m)
        reference[mat] = {"fixed": f"{fixed}.nii.gz", "moving": f"{moving}.nii.gz", "ras": read.matrix.tolist()}
    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")


if __name__ == "__main__":
    main()
