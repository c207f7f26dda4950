#!/usr/bin/env python3
"""OME-Zarr written by `warpbench warp --out x.ome.zarr` and `warpbench field --out u.ome.zarr`, checked by ngff-zarr
0.50 (the reference implementation of RFC-4's anatomical orientation and RFC-5's displacement fields) against ITK.

For each source volume (RAS NIfTIs, a CT atlas, an OME-Zarr image of permuted and reversed axes): `warpbench
warp` with identity pairs (affine) writes the source onto its own grid as OME-Zarr; ngff-zarr reads the store with `validate=True` (the OME-Zarr 0.5 JSON schemas) and converts it to an ITK
image (`ngff_image_to_itk_image`); ITK reads the source itself (ngff-zarr the OME-Zarr one). Every source voxel's physical point must fall on a
voxel centre of ngff-zarr's image (to 1e-4 voxel) holding the same value. Then `warpbench field` writes one pull-back
as OME-Zarr 0.6 and as ITK's NIfTI: ngff-zarr validates the store against the 0.6 schemas and converts it to an ITK
displacement field with no other information, whose vectors must be those ITK reads from the NIfTI, voxel for voxel
(1e-5 mm). The script prints one line per check and exits 1 if any fails.

Run from the repository root after `cargo build -p warpbench-app`, in a venv with ngff-zarr 0.50.0, zarr 3.1.6 and
itk 5.4.7 (`pip install "ngff-zarr[validate]==0.50.0" "zarr==3.1.6" "itk==5.4.7"`):

    python data-scripts/check_ngff_write.py [--bin target/debug/warpbench]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import itk
import ngff_zarr
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SOURCES = [
    "tests/data/nifti/avg152T1_LR_nifti.nii",
    "tests/data/nifti/anatomical.nii",
    "tests/data/nifti/ct_brain_atlas_1mm.nii.gz",
    # (No MINC: ITK's MINC reader takes MINC's RAS world as LPS unless told otherwise; crates/python/tests/
    # test_ngff_write.py checks a MINC volume against nibabel.)
    # ngff-zarr's own image of permuted, reversed axes (tests/data/ngff/README.md), read here by ngff-zarr.
    "tests/data/ngff/v05_u16_oriented.ome.zarr",
]


def read_source(source: Path):
    """The source as an ITK image: ITK reads it, or ngff-zarr an OME-Zarr one."""
    if source.suffix == ".zarr":
        return ngff_zarr.ngff_image_to_itk_image(ngff_zarr.from_ngff_zarr(str(source)).images[0], wasm=False)
    return itk.imread(str(source))


def index_from_physical(image) -> tuple[np.ndarray, np.ndarray]:
    """(M, o) with continuous index = M (p − o), p a physical point: ITK's own map, as arrays."""
    direction = itk.array_from_matrix(image.GetDirection())
    spacing = np.array(image.GetSpacing())
    return np.linalg.inv(direction @ np.diag(spacing)), np.array(image.GetOrigin())


def check(binary: Path, source: Path, scratch: Path) -> str | None:
    """None when warpbench's store of `source` agrees with ITK's reading of it, else what differs."""
    original = read_source(source)
    # Identity pairs inside the volume: its centre and a quarter of the way to three faces.
    size = np.array(itk.size(original)) - 1.0
    direction = itk.array_from_matrix(original.GetDirection())
    lps_from_index = direction @ np.diag(original.GetSpacing())
    at = [size / 2 + np.eye(3)[a] * size / 4 if a < 3 else size / 2 for a in range(4)]
    points = [lps_from_index @ c + np.array(original.GetOrigin()) for c in at]
    pairs = scratch / "identity.csv"
    pairs.write_text("".join(f'"Pt-{n}","true",{x},{y},{z},{x},{y},{z}\n' for n, (x, y, z) in enumerate(points)))
    store = scratch / f"{source.name}.ome.zarr"
    subprocess.run(
        [binary, "warp", "--fixed", source, "--moving", source, "--landmarks", pairs, "--method", "affine",
         "--backend", "cpu", "--quiet", "--force", "--out", store],
        check=True,
    )
    multiscales = ngff_zarr.from_ngff_zarr(str(store), validate=True)
    written = ngff_zarr.ngff_image_to_itk_image(multiscales.images[0], wasm=False)
    values = itk.array_view_from_image(original)  # (k, j, i)
    stored = itk.array_view_from_image(written)
    k, j, i = np.indices(values.shape).reshape(3, -1)
    points = lps_from_index @ np.stack([i, j, k]) + np.array(original.GetOrigin())[:, None]
    m, o = index_from_physical(written)
    index = m @ (points - o[:, None])
    rounded = np.rint(index)
    if np.abs(index - rounded).max() > 1e-4:
        return f"a voxel {np.abs(index - rounded).max():.2e} voxel off the written centres"
    x, y, z = rounded.astype(int)
    if min(x.min(), y.min(), z.min()) < 0 or x.max() >= stored.shape[2] or y.max() >= stored.shape[1] or z.max() >= stored.shape[0]:
        return "a voxel outside the written image"
    got, want = stored[z, y, x], values.reshape(-1)
    if got.dtype.kind == "f" or want.dtype.kind == "f":
        ok = np.allclose(got, want, rtol=1e-6, atol=1e-6 * float(np.abs(want).max()))
    else:
        ok = np.array_equal(got, want)
    return None if ok else f"values differ at {int(np.sum(got != want))} voxels"


def check_field(binary: Path, scratch: Path) -> str | None:
    """None when `warpbench field --out u.ome.zarr` is, as ngff-zarr reads it back as an ITK displacement field (with
    no other information), the field ITK reads from `warpbench field --out u.nii.gz` (ITK's DISPVECT NIfTI), else
    what differs."""
    fixed, pairs = ROOT / "tests/data/nifti/avg152T1_LR_nifti.nii", ROOT / "tests/data/itk/field_pairs.csv"
    stores = {}
    for name in ("u.ome.zarr", "u.nii.gz"):
        stores[name] = scratch / name
        subprocess.run(
            [binary, "field", "--fixed", fixed, "--moving", fixed, "--landmarks", pairs, "--quiet", "--force",
             "--out", stores[name]],
            check=True,
        )
    multiscales = ngff_zarr.from_ngff_zarr(str(stores["u.ome.zarr"]), validate=True)
    transform = next(t for t in multiscales.metadata.coordinateTransformations if t.type == "displacements")
    (entry,) = ngff_zarr.ngff_displacement_field_to_itk_transform(transform, multiscales, ["z", "y", "x"])
    fixed_parameters = np.asarray(entry.fixedParameters)
    size = fixed_parameters[:3].astype(int)
    origin, spacing = fixed_parameters[3:6], fixed_parameters[6:9]
    direction = fixed_parameters[9:18].reshape(3, 3)
    theirs = np.asarray(entry.parameters).reshape(size[2], size[1], size[0], 3)
    nifti = itk.imread(str(stores["u.nii.gz"]))
    vectors = itk.array_view_from_image(nifti)  # (k, j, i, c), LPS: ITK converts DISPVECT's RAS vectors
    k, j, i = np.indices(vectors.shape[:3]).reshape(3, -1)
    d = itk.array_from_matrix(nifti.GetDirection()) @ np.diag(nifti.GetSpacing())
    points = d @ np.stack([i, j, k]) + np.array(nifti.GetOrigin())[:, None]
    index = np.linalg.inv(direction @ np.diag(spacing)) @ (points - origin[:, None])
    rounded = np.rint(index)
    if np.abs(index - rounded).max() > 1e-4:
        return "the field's grid points are not the NIfTI's"
    x, y, z = rounded.astype(int)
    got, want = theirs[z, y, x], vectors.reshape(-1, 3)
    err = float(np.abs(got - want).max())
    return None if err <= 1e-5 else f"vectors differ by up to {err} mm"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", type=Path, default=ROOT / "target" / "debug" / "warpbench")
    args = ap.parse_args()
    failed = 0
    with tempfile.TemporaryDirectory() as scratch:
        for name in SOURCES:
            problem = check(args.bin, ROOT / name, Path(scratch))
            print(f"{name}: {'agrees with ITK (schema-valid 0.5)' if problem is None else problem}")
            failed += problem is not None
        problem = check_field(args.bin, Path(scratch))
        print(f"field --out u.ome.zarr: {'is, to ngff-zarr, the field ITK reads from u.nii.gz' if problem is None else problem}")
        failed += problem is not None
    print(f"ngff-zarr {ngff_zarr.__version__}, itk {itk.__version__}, numpy {np.__version__}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
