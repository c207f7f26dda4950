#!/usr/bin/env python3
"""AFNI datasets (`.HEAD` + `.BRIK`) for `crates/io/tests/afni_dataset.rs`, with what nibabel and nitransforms read
from them.

Copies into tests/data/afni/ the two AFNI datasets of nibabel 5.4.2's own test data (written by AFNI):

- `example4d+orig.HEAD`, `example4d+orig.BRIK.gz`: three short sub-bricks, gzip-compressed;
- `scaled+tlrc.HEAD`, `scaled+tlrc.BRIK`: one short sub-brick with a scale factor (BRICK_FLOAT_FACS);
- `bad_attribute+orig.HEAD`, `bad_datatype+orig.HEAD`: example4d's header with `BYTEORDER_STRING` typed as an
  integer, and with a complex sub-brick, which nibabel refuses (no `.BRIK`: nibabel's tests give none).

Writes into tests/data/afni_made/:

- `warp_rai+tlrc.HEAD`, `.BRIK`: a 3dQwarp-style warp (three float sub-bricks labelled x_delta, y_delta, z_delta,
  as AFNI's `IW3D_to_dataset` writes them) on a 14 x 16 x 12 grid, 2.5 x 2 x 3 mm, in AFNI's usual RAI order,
  little-endian, with IJK_TO_DICOM_REAL;
- `warp_lps+orig.HEAD`, `.BRIK.gz`: another warp on an L-P-I grid, big-endian, gzip-compressed, and without
  IJK_TO_DICOM_REAL (as AFNI wrote before 2007), so that its geometry comes from ORIENT_SPECIFIC, ORIGIN and DELTA;
- `warp_rai_WARP.nii.gz`: the first warp as AFNI saves a warp named `.nii.gz` (`3dQwarp -prefix x.nii.gz`, AFNI's
  `THD_write_nifti`): an (X, Y, Z, 1, 3) float32 array of the same DICOM-order deltas, intent 0, sform and qform
  code 3 (Talairach, the `+tlrc` view), and AFNI's extension (code 4) whose NIML labels the sub-bricks;
- `nitransforms_afni.nii.gz`: the same warp as nitransforms' own writer saves it (`to_filename(fmt="afni")`): no AFNI
  extension, so nothing in the file says it is a warp; warpbench refuses it;
- `reference.json`: for each copied dataset, nibabel's affine (made LPS) and, at 40 seeded voxels of every
  sub-brick, nibabel's value (`get_fdata`, scale factor applied); for each warp, at 60 voxel centres (the eight
  corners and seeded ones), the point nitransforms maps it to (`DenseFieldTransform` of the warp in AFNI's NIfTI
  form, `fmt="afni"`), in LPS mm.

nibabel reads each warp's header (`nibabel.brikhead`), which checks that the script writes AFNI's attribute syntax:
the warp's values and grid come back as written before nitransforms maps anything.

Run: target/ci-python-venv/bin/python data-scripts/afni_fixtures.py (nibabel 5.4.2, nitransforms 25.1.0, as
`.ci/run` installs them). Output is reproducible (seeded; gzip's time field zeroed).
"""

from __future__ import annotations

import gzip
import json
import shutil
import tempfile
from pathlib import Path

import nibabel as nib
import numpy as np
from nitransforms.nonlinear import DenseFieldTransform

ROOT = Path(__file__).resolve().parent.parent
COPIES = ROOT / "tests" / "data" / "afni"
MADE = ROOT / "tests" / "data" / "afni_made"
SEED = 20261207
NIBABEL_DATA = Path(nib.__file__).parent / "tests" / "data"
COPIED = {
    "example4d+orig": ("example4d+orig.HEAD", "example4d+orig.BRIK.gz"),
    "scaled+tlrc": ("scaled+tlrc.HEAD", "scaled+tlrc.BRIK"),
}
# nibabel's two damaged headers (example4d's, one attribute changed), which nibabel refuses.
BAD = ("bad_attribute+orig.HEAD", "bad_datatype+orig.HEAD")
LPS_FROM_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


def attribute(kind: str, name: str, values) -> str:
    """One attribute as AFNI's `THD_write_atr` lays it out."""
    if kind == "string":
        text = f"'{values}~"
        return f"\ntype = string-attribute\nname = {name}\ncount = {len(text) - 1}\n{text}\n"
    if kind == "integer":
        rows = [" ".join(f"{v:d}" for v in values[k:k + 5]) for k in range(0, len(values), 5)]
        return f"\ntype = integer-attribute\nname = {name}\ncount = {len(values)}\n " + "\n ".join(rows) + "\n"
    rows = [" ".join(f"{v:14.7g}" for v in values[k:k + 5]) for k in range(0, len(values), 5)]
    return f"\ntype  = float-attribute\nname  = {name}\ncount = {len(values)}\n" + "\n".join(rows) + "\n"


def warp_head(shape, orient, origin, delta, big_endian: bool, real: bool) -> str:
    rows = {code // 2: a for a, code in enumerate(orient)}
    m = np.zeros((3, 4))
    for row, a in rows.items():
        m[row, a] = delta[a]
        m[row, 3] = origin[a]
    parts = [
        attribute("string", "TYPESTRING", "3DIM_HEAD_ANAT"),
        attribute("string", "IDCODE_STRING", "AFN_warpbench_fixture_0001"),
        attribute("integer", "SCENE_DATA", [2, 0, 0, -999, -999, -999, -999, -999]),
        attribute("integer", "ORIENT_SPECIFIC", list(orient)),
        attribute("float", "ORIGIN", list(origin)),
        attribute("float", "DELTA", list(delta)),
        attribute("float", "IJK_TO_DICOM", list(m.ravel())),
    ]
    if real:
        parts.append(attribute("float", "IJK_TO_DICOM_REAL", list(m.ravel())))
    parts += [
        attribute("integer", "DATASET_RANK", [3, 3, 0, 0, 0, 0, 0, 0]),
        attribute("integer", "DATASET_DIMENSIONS", [*shape, 0, 0]),
        attribute("integer", "BRICK_TYPES", [3, 3, 3]),
        attribute("float", "BRICK_FLOAT_FACS", [0.0, 0.0, 0.0]),
        attribute("string", "BRICK_LABS", "x_delta~y_delta~z_delta"),
        attribute("string", "BYTEORDER_STRING", "MSB_FIRST" if big_endian else "LSB_FIRST"),
    ]
    return "".join(parts), m


def smooth_warp(shape, rng) -> np.ndarray:
    """Three smooth displacement components of a few mm, (X, Y, Z, 3)."""
    grids = np.meshgrid(*(np.linspace(0.0, 1.0, n) for n in shape), indexing="ij")
    out = np.zeros((*shape, 3))
    for c in range(3):
        for _ in range(2):
            a, f, p = rng.uniform(1.0, 3.0), rng.uniform(0.5, 1.5, 3), rng.uniform(0, 2 * np.pi, 3)
            out[..., c] += a * np.prod([np.sin(np.pi * f[d] * grids[d] + p[d]) for d in range(3)], axis=0)
    return out.astype(np.float32)


def voxels(shape, rng, n: int) -> np.ndarray:
    corners = np.array([[i, j, k] for i in (0, shape[0] - 1) for j in (0, shape[1] - 1) for k in (0, shape[2] - 1)])
    seeded = np.stack([rng.integers(0, s, n - len(corners)) for s in shape], axis=1)
    return np.concatenate([corners, seeded])


NIML = """<?xml version='1.0' ?>
<AFNI_attributes
  self_idcode="AFN_warpbench_fixture_0001"
  NIfTI_nums="{nums}"
  ni_form="ni_group" >
<AFNI_atr
  ni_type="String"
  ni_dimen="1"
  atr_name="TYPESTRING" >
 "3DIM_HEAD_ANAT"
</AFNI_atr>
<AFNI_atr
  ni_type="String"
  ni_dimen="1"
  atr_name="BRICK_LABS" >
 "x_delta~y_delta~z_delta"
</AFNI_atr>
</AFNI_attributes>
"""


def save_nifti(img: nib.Nifti1Image, path: Path) -> None:
    img.to_filename(path)
    raw = gzip.decompress(path.read_bytes())
    path.write_bytes(gzip.compress(raw, compresslevel=9, mtime=0))


def write_nifti_forms(field: np.ndarray, affine: np.ndarray, xfm_reference) -> None:
    """The warp as AFNI writes it to NIfTI (with its extension), and as nitransforms does (without)."""
    shape = field.shape[:3]
    img = nib.Nifti1Image(field.reshape(*shape, 1, 3), affine)
    img.header.set_sform(affine, code=3)
    img.header.set_qform(affine, code=3)
    nums = ",".join(str(n) for n in (*shape, 1, 3, 16))
    img.header.extensions.append(nib.nifti1.Nifti1Extension(4, NIML.format(nums=nums).encode() + b"\0"))
    path = MADE / "warp_rai_WARP.nii.gz"
    save_nifti(img, path)
    # nitransforms reads AFNI's file to the same map as the dataset.
    ras, mapped = xfm_reference
    again = DenseFieldTransform.from_filename(path, fmt="afni").map(ras)
    assert np.allclose(again, mapped, atol=1e-5)
    out = MADE / "nitransforms_afni.nii.gz"
    DenseFieldTransform.from_filename(path, fmt="afni").to_filename(out, fmt="afni")
    save_nifti(nib.load(out), out)
    assert not nib.load(out).header.extensions


def write_warp(stem: str, shape, orient, origin, delta, big_endian: bool, real: bool, gz: bool, rng) -> dict:
    head, m = warp_head(shape, orient, origin, delta, big_endian, real)
    field = smooth_warp(shape, rng)
    # Sub-bricks one after another, each i fastest (Fortran order).
    dtype = ">f4" if big_endian else "<f4"
    raw = b"".join(np.asarray(field[..., c], dtype=dtype).tobytes(order="F") for c in range(3))
    (MADE / f"{stem}.HEAD").write_text(head)
    brik = MADE / (f"{stem}.BRIK.gz" if gz else f"{stem}.BRIK")
    for old in MADE.glob(f"{stem}.BRIK*"):
        old.unlink()
    brik.write_bytes(gzip.compress(raw, compresslevel=9, mtime=0) if gz else raw)

    # nibabel reads the header as AFNI's (a copy with IJK_TO_DICOM_REAL, which nibabel needs, when the fixture has
    # none): the grid and the values come back as written.
    with tempfile.TemporaryDirectory() as tmp:
        full, _ = warp_head(shape, orient, origin, delta, big_endian, True)
        (Path(tmp) / f"{stem}.HEAD").write_text(full)
        (Path(tmp) / f"{stem}.BRIK").write_bytes(raw)
        img = nib.load(Path(tmp) / f"{stem}.HEAD")
        assert np.array_equal(np.asanyarray(img.dataobj), field), stem
        affine = img.affine
        assert np.allclose(LPS_FROM_RAS @ affine, np.vstack([m, [0, 0, 0, 1]])), stem
        # AFNI's NIfTI form of the warp (what 3dAFNItoNIFTI makes: (X, Y, Z, 1, 3), the DICOM deltas), read by
        # nitransforms as AFNI's.
        nii = Path(tmp) / f"{stem}.nii"
        nib.Nifti1Image(field.reshape(*shape, 1, 3), affine).to_filename(nii)
        xfm = DenseFieldTransform.from_filename(nii, fmt="afni")
        ijk = voxels(shape, rng, 60)
        ras = nib.affines.apply_affine(affine, ijk)
        mapped = xfm.map(ras)
    if stem == "warp_rai+tlrc":
        write_nifti_forms(field, affine, (ras, mapped))
    lps = lambda p: (p * [-1.0, -1.0, 1.0]).tolist()  # noqa: E731
    return {
        "dims": list(shape),
        "lps_from_index": np.vstack([m, [0, 0, 0, 1]]).tolist(),
        "voxels": ijk.tolist(),
        "fixed_lps": lps(ras),
        "nitransforms_lps": lps(np.asarray(mapped)),
    }


def copied_reference(stem: str, rng) -> dict:
    img = nib.load(COPIES / COPIED[stem][0])
    data = img.get_fdata()
    if data.ndim == 3:
        data = data[..., None]
    ijk = voxels(data.shape[:3], rng, 40)
    return {
        "dims": list(data.shape[:3]),
        "sub_bricks": data.shape[3],
        "labels": img.header.get_volume_labels(),
        "lps_from_index": (LPS_FROM_RAS @ img.affine).tolist(),
        "voxels": ijk.tolist(),
        "values": [[float(data[i, j, k, t]) for i, j, k in ijk] for t in range(data.shape[3])],
    }


def main() -> int:
    COPIES.mkdir(parents=True, exist_ok=True)
    MADE.mkdir(parents=True, exist_ok=True)
    for names in [*COPIED.values(), BAD]:
        for name in names:
            shutil.copyfile(NIBABEL_DATA / name, COPIES / name)
    rng = np.random.default_rng(SEED)
    reference = {
        "nibabel": nib.__version__,
        "datasets": {stem: copied_reference(stem, rng) for stem in COPIED},
        "warps": {
            "warp_rai+tlrc": write_warp(
                "warp_rai+tlrc", (14, 16, 12), (0, 3, 4), (-16.25, -15.0, -18.0), (2.5, 2.0, 3.0),
                big_endian=False, real=True, gz=False, rng=rng,
            ),
            "warp_lps+orig": write_warp(
                "warp_lps+orig", (12, 10, 14), (1, 2, 5), (13.0, 11.0, 20.0), (-2.0, -2.5, -3.0),
                big_endian=True, real=False, gz=True, rng=rng,
            ),
        },
    }
    (MADE / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    print(f"wrote {COPIES} and {MADE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
