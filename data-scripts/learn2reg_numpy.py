#!/usr/bin/env python3
"""Learn2Reg displacement fields as NumPy and nibabel write them, for the reader's tests.

Writes into tests/data/learn2reg/ one field of shape (X, Y, Z, 3) = (5, 4, 2, 3), in voxels, with values the script
makes up (d[i, j, k, c] = 0.25 * (c + 1) * (i - 2) + 0.125 * j - 0.5 * k + 0.0625 * c, exact in float16):
- disp_f16.npz: `np.savez_compressed(path, disp.astype(np.float16))`, what Learn2Reg's submissions are (array arr_0);
- disp_f32_fortran.npz: `np.savez(path, np.asfortranarray(disp.astype(np.float32)))`: stored, Fortran order;
- disp_f64_named.npz: `np.savez(path, disp=disp)`: one array, not named arr_0, float64, big-endian;
- disp_2021.npz: `np.savez_compressed(path, disp.transpose(3, 0, 1, 2))`: the 2021 layout (3, X, Y, Z), refused;
- two_arrays.npz: `np.savez(path, a=disp, b=disp)`: two arrays and no arr_0, refused;
- the challenge's NIfTI form since 2022, `nib.save(nib.Nifti1Image(disp, affine), path)` as its methods write it:
  disp_nibabel_f32.nii.gz (float32 with an image's affine, as ConvexAdam), disp_nibabel_f64_eye.nii (float64,
  np.eye(4), as the challenge's zero fields) and disp_nibabel_noaffine.nii.gz (float32, affine None);
- reference.json: the shape and d as nested lists [i][j][k][c], what numpy.load and nibabel's get_fdata return for
  every readable file.

Run from the repository root with numpy 2.4.6 and nibabel 5.4.2, the versions .ci/run installs into
target/ci-python-venv (target/ci-python-venv/bin/python data-scripts/learn2reg_numpy.py). The .npz bytes hold the
zip entries' times and the .nii.gz bytes gzip's, so a rerun's bytes differ; the arrays do not.
"""

from __future__ import annotations

import json
from pathlib import Path

import nibabel as nib
import numpy as np

OUT = Path("tests/data/learn2reg")


def field() -> np.ndarray:
    i, j, k = np.meshgrid(np.arange(5), np.arange(4), np.arange(2), indexing="ij")
    d = np.stack([0.25 * (c + 1) * (i - 2) + 0.125 * j - 0.5 * k + 0.0625 * c for c in range(3)], axis=-1)
    assert d.shape == (5, 4, 2, 3)
    assert np.array_equal(d.astype(np.float16).astype(np.float64), d), "the values must be exact in float16"
    return d


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    d = field()
    np.savez_compressed(OUT / "disp_f16.npz", d.astype(np.float16))
    np.savez(OUT / "disp_f32_fortran.npz", np.asfortranarray(d.astype(np.float32)))
    np.savez(OUT / "disp_f64_named.npz", disp=d.astype(">f8"))
    np.savez_compressed(OUT / "disp_2021.npz", d.transpose(3, 0, 1, 2))
    np.savez(OUT / "two_arrays.npz", a=d, b=d)
    for name in ("disp_f16.npz", "disp_f32_fortran.npz", "disp_f64_named.npz"):
        with np.load(OUT / name) as z:
            (array,) = z.values()
            assert np.array_equal(array.astype(np.float64), d), name
    image_affine = np.array([[-2.0, 0, 0, 90], [0, 2.5, 0, -126], [0, 0, 3, -72], [0, 0, 0, 1]])
    nib.save(nib.Nifti1Image(d.astype(np.float32), image_affine), OUT / "disp_nibabel_f32.nii.gz")
    nib.save(nib.Nifti1Image(d, np.eye(4)), OUT / "disp_nibabel_f64_eye.nii")
    nib.save(nib.Nifti1Image(d.astype(np.float32), None), OUT / "disp_nibabel_noaffine.nii.gz")
    for name in ("disp_nibabel_f32.nii.gz", "disp_nibabel_f64_eye.nii", "disp_nibabel_noaffine.nii.gz"):
        image = nib.load(OUT / name)
        assert image.header["dim"][0] == 4 and image.header["intent_code"] == 0, name
        assert np.array_equal(image.get_fdata(), d), name
    reference = {"numpy": np.__version__, "nibabel": nib.__version__, "shape": list(d.shape), "disp": d.tolist()}
    (OUT / "reference.json").write_text(json.dumps(reference) + "\n")


if __name__ == "__main__":
    main()
