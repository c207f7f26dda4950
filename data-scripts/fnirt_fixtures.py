#!/usr/bin/env python3
"""FSL FNIRT warps for `crates/io/tests/fnirt.rs`, written and read back by fslpy (FSL's own Python library, whose
`fsl.transform.fnirt` and `fsl.transform.nonlinear` read and write FNIRT's files as `fnirt_file_writer.cpp` and
`fnirtfileutils` do).

Writes into tests/data/fnirt/:

- `ref_neuro.nii.gz`, `ref_radio.nii.gz`: two reference images (20 × 24 × 18, 2 × 2.5 × 3 mm), the first with a
  positive voxel-to-world determinant (FSL reverses its first axis), the second with a negative one;
- `src.nii.gz`: the source image (22 × 20 × 16, 1.5 × 2 × 2.5 mm, rotated 10° about z, negative determinant);
- `coef_neuro.nii.gz`: FNIRT cubic B-spline coefficients (knot spacing 4, 4, 3 voxels) over `ref_neuro`, with a
  starting affine (a rotation of 4° and a shift), as `fnirt --cout` writes them (`fnirt.toFnirt`);
- `coef_radio.nii.gz`: the same coefficients over `ref_radio`, starting affine the identity;
- `field_rel.nii.gz`, `field_abs.nii.gz`: `coef_neuro` as a deformation field of relative displacements (as
  `fnirt --fout` writes it) and of absolute positions (as `convertwarp --absout` does);
- `coef_quadratic.nii.gz`, `topup_field.nii.gz`: `coef_radio` with the intent of quadratic coefficients (2009) and
  of a TOPUP field (2018), which warpbench refuses;
- `reference.json`: for each warp, at 60 reference voxels (the eight corners and seeded ones), the source point fslpy
  maps it to (`readFnirt(...).transform(voxels, from_="voxel", to="world")`), in LPS mm, and for each deformation
  field the type fslpy detects.

Run: python3 -m venv /tmp/fslvenv && /tmp/fslvenv/bin/pip install fslpy==3.29.1 nibabel==5.4.2 numpy==2.4.6
scipy==1.17.1, then /tmp/fslvenv/bin/python data-scripts/fnirt_fixtures.py. Output is reproducible (seeded).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import nibabel as nib
import numpy as np
from fsl.data.image import Image
from fsl.transform import affine, fnirt, nonlinear

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "fnirt"
SEED = 20261207
REF_SHAPE = (20, 24, 18)
REF_SPACING = (2.0, 2.5, 3.0)
KNOTS = (4.0, 4.0, 3.0)


def save(img: nib.Nifti1Image, name: str) -> Path:
    img.header["descrip"] = b"warpbench test fixture"
    path = OUT / name
    # gzip's mtime is fixed so that the file is the same bytes on every run.
    nib.openers.Opener.default_compresslevel = 9
    img.to_filename(path)
    raw = path.read_bytes()
    path.write_bytes(raw[:4] + b"\0\0\0\0" + raw[8:])
    return path


def image(shape, spacing, det_positive: bool, rotate_deg: float = 0.0, origin=(0.0, 0.0, 0.0)) -> nib.Nifti1Image:
    c, s = math.cos(math.radians(rotate_deg)), math.sin(math.radians(rotate_deg))
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    lin = rot @ np.diag(spacing)
    if not det_positive:
        lin[:, 0] *= -1
    aff = np.eye(4)
    aff[:3, :3] = lin
    aff[:3, 3] = origin
    img = nib.Nifti1Image(np.zeros(shape, np.uint8), aff)
    img.set_sform(aff, 1)
    img.set_qform(aff, 1)
    return img


def coefficients(rng: np.random.Generator) -> np.ndarray:
    shape = tuple(int(math.ceil(n / k)) + 3 for n, k in zip(REF_SHAPE, KNOTS)) + (3,)
    return (rng.standard_normal(shape) * 2.5).astype(np.float32)


def premat(angle_deg: float, shift) -> np.ndarray:
    return affine.compose([1, 1, 1], shift, [0, 0, math.radians(angle_deg)], origin=[20, 30, 27])


def coefficient_field(coefs, src: Image, ref: Image, src_to_ref) -> nonlinear.CoefficientField:
    field = nonlinear.CoefficientField(
        nib.Nifti1Image(coefs, np.eye(4)),
        src=src,
        ref=ref,
        srcSpace="fsl",
        refSpace="fsl",
        fieldType="cubic",
        knotSpacing=KNOTS,
        fieldToRefMat=affine.scaleOffsetXform(KNOTS, 0),
        srcToRefMat=src_to_ref,
    )
    return fnirt.toFnirt(field)


def sample_voxels(rng: np.random.Generator) -> np.ndarray:
    corners = np.array([[i, j, k] for i in (0, REF_SHAPE[0] - 1) for j in (0, REF_SHAPE[1] - 1) for k in (0, REF_SHAPE[2] - 1)])
    seeded = np.stack([rng.integers(0, n, 52) for n in REF_SHAPE], axis=1)
    return np.concatenate([corners, seeded]).astype(float)


def lps(ras: np.ndarray) -> list[list[float]]:
    return (ras * np.array([-1.0, -1.0, 1.0])).tolist()


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    paths = {
        "ref_neuro": save(image(REF_SHAPE, REF_SPACING, True, origin=(-20.0, -30.0, -25.0)), "ref_neuro.nii.gz"),
        "ref_radio": save(image(REF_SHAPE, REF_SPACING, False, origin=(18.0, -30.0, -25.0)), "ref_radio.nii.gz"),
        "src": save(image((22, 20, 16), (1.5, 2.0, 2.5), False, rotate_deg=10.0, origin=(16.0, -22.0, -20.0)), "src.nii.gz"),
    }
    src = Image(str(paths["src"]))
    refs = {name: Image(str(paths[name])) for name in ("ref_neuro", "ref_radio")}
    coefs = coefficients(rng)
    voxels = sample_voxels(rng)
    reference: dict = {"voxels": voxels.astype(int).tolist(), "warps": {}}

    def record(name: str, ref_name: str, extra: dict | None = None) -> None:
        warp = fnirt.readFnirt(str(OUT / name), src, refs[ref_name])
        world = warp.transform(voxels, from_="voxel", to="world")
        entry = {"reference": ref_name, "source": "src", "moving_lps": lps(world)}
        if isinstance(warp, nonlinear.DeformationField):
            entry["detected"] = warp.deformationType
        entry.update(extra or {})
        reference["warps"][name] = entry

    neuro = coefficient_field(coefs, src, refs["ref_neuro"], premat(4.0, [3.0, -2.0, 1.5]))
    save(nib.Nifti1Image(neuro.data, None, neuro.header), "coef_neuro.nii.gz")
    record("coef_neuro.nii.gz", "ref_neuro")
    radio = coefficient_field(coefs, src, refs["ref_radio"], None)
    save(nib.Nifti1Image(radio.data, None, radio.header), "coef_radio.nii.gz")
    record("coef_radio.nii.gz", "ref_radio")

    read = fnirt.readFnirt(str(OUT / "coef_neuro.nii.gz"), src, refs["ref_neuro"])
    for def_type, name in (("relative", "field_rel.nii.gz"), ("absolute", "field_abs.nii.gz")):
        field = fnirt.toFnirt(nonlinear.coefficientFieldToDeformationField(read, defType=def_type, premat=True))
        img = nib.Nifti1Image(field.data.astype(np.float32), refs["ref_neuro"].voxToWorldMat, field.header)
        img.header.set_data_dtype(np.float32)
        img.header["intent_code"] = 2006
        save(img, name)
        record(name, "ref_neuro", {"written_as": def_type})

    radio_img = nib.load(OUT / "coef_radio.nii.gz")
    for intent, name in ((2009, "coef_quadratic.nii.gz"), (2018, "topup_field.nii.gz")):
        img = nib.Nifti1Image(np.asanyarray(radio_img.dataobj), None, radio_img.header.copy())
        img.header["intent_code"] = intent
        save(img, name)

    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")


if __name__ == "__main__":
    main()
