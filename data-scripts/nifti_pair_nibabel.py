#!/usr/bin/env python3
"""NIfTI pairs (`.hdr` + `.img`, magic `ni1` / `ni2`) written by nibabel, and what nibabel reads from each.

A NIfTI pair is the header of a NIfTI file in a `.hdr` and its samples in a `.img` beside it, from byte `vox_offset`
(SPM's and older tools' habit; either may be gzip-compressed). nibabel 5.4.2 (`Nifti1Pair`, `Nifti2Pair`) writes them
here, into tests/data/nifti_pair/:

- `oblique_i16.{hdr,img}`: NIfTI-1, 5 x 4 x 3, int16 with a scale (nibabel picks scl_slope and scl_inter for the
  half-integer values), on an oblique grid with unequal voxel sizes (sform and qform, code 1);
- `frames_f32.{hdr,img}`: NIfTI-2, float32, 4 x 3 x 2 x 2 (two frames), LAS;
- `big_endian_u16.{hdr,img}`: NIfTI-1, big-endian, uint16, a grid with a negative determinant;
- `compressed_u8.{hdr.gz,img.gz}`: NIfTI-1, uint8, both files gzip-compressed (nibabel's `.img.gz` naming);
- `analyze.{hdr,img}`: Analyze 7.5 (no NIfTI magic), which warpbench refuses: its orientation is not stored.

`reference.json` holds, for each NIfTI pair, nibabel's affine (RAS, 0-based indices), the shape and the values
(`get_fdata()`, i fastest, frame after frame). gzip stamps the time, so a rerun's `.gz` bytes differ; the others and
the reference do not.

Usage, from the repository root (a Python with nibabel 5.4.2 and numpy 2.4.6, e.g. the venv `.ci/run` makes):

    target/ci-python-venv/bin/python data-scripts/nifti_pair_nibabel.py
"""

from __future__ import annotations

import json
from pathlib import Path

import nibabel as nib
import numpy as np
from fixture_grids import affine, rotation

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "nifti_pair"


def pair(name: str, image, ext: str = "img") -> dict:
    path = OUT / f"{name}.{ext}"
    image.set_sform(image.affine, code=1)
    image.set_qform(image.affine, code=1)
    image.to_filename(path)
    back = nib.load(path)
    data = back.get_fdata()
    return {
        "files": sorted(p.name for p in OUT.glob(f"{name}.*")),
        "affine": back.affine.tolist(),
        "shape": list(data.shape),
        "values": data.ravel(order="F").tolist(),
    }


def main() -> None:
    assert nib.__version__ == "5.4.2", nib.__version__
    OUT.mkdir(parents=True, exist_ok=True)
    for old in OUT.iterdir():
        old.unlink()
    reference = {"nibabel": nib.__version__, "pairs": {}}

    oblique = affine(rotation(0.2, -0.1, 0.3) @ np.diag([0.8, 1.1, 2.5]), (-20.0, 15.0, 7.5))
    values = (np.arange(60, dtype=np.float64) * 0.5 - 7.0).reshape((5, 4, 3), order="F")
    header = nib.Nifti1Header()
    header.set_data_dtype(np.int16)
    reference["pairs"]["oblique_i16"] = pair("oblique_i16", nib.Nifti1Pair(values, oblique, header))

    las = affine(np.diag([-1.5, 1.25, 2.0]), (30.0, -20.0, -10.0))
    frames = np.arange(48, dtype=np.float32).reshape((4, 3, 2, 2), order="F") / 3.0
    reference["pairs"]["frames_f32"] = pair("frames_f32", nib.Nifti2Pair(frames, las))

    flipped = affine(rotation(-0.1, 0.05, 0.0) @ np.diag([-1.0, 1.0, 1.2]), (5.0, 6.0, -7.0))
    big = nib.Nifti1Header(endianness=">")
    big.set_data_dtype(np.uint16)
    counts = (np.arange(24, dtype=np.uint16) * 2500).reshape((2, 3, 4), order="F")
    reference["pairs"]["big_endian_u16"] = pair("big_endian_u16", nib.Nifti1Pair(counts, flipped, big))

    small = np.arange(27, dtype=np.uint8).reshape((3, 3, 3), order="F") * 9
    straight = affine(np.diag([2.0, 2.0, 2.0]), (-2.0, -2.0, -2.0))
    reference["pairs"]["compressed_u8"] = pair("compressed_u8", nib.Nifti1Pair(small, straight), "img.gz")

    nib.AnalyzeImage(small, straight).to_filename(OUT / "analyze.img")
    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")


if __name__ == "__main__":
    main()
