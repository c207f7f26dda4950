#!/usr/bin/env python3
"""OME-Zarr 0.6 displacement-field fixtures (RFC-5's `displacements`), written by ngff-zarr 0.50, the reference
implementation, for `crates/io/tests/ngff.rs` and `crates/python/tests/test_ngff_field.py`.

Each field is a 4 × 5 × 6 (x, y, z) ITK displacement field of smooth, distinct float32 vectors, converted by
`ngff_zarr.itk_displacement_field_to_ngff_transform` and declared by `declare_field_transform`, written with
`to_ngff_zarr(..., version="0.6")`:

- `field_plain.ome.zarr`: the field alone, no unit and no orientation (what ngff-zarr makes of an ITK field);
- `field_lps_mm.ome.zarr`: converted against a fixed and a moving image in one frame, in millimetres, with ngff-zarr's
  RFC-4 orientations of ITK's LPS (`right-to-left`, `anterior-to-posterior`, `inferior-to-superior`);
- `field_um.ome.zarr`: the same in micrometres (grid and vectors, numbers unchanged, as ngff-zarr keeps them);
- `image_with_field.ome.zarr`: an image whose multiscale declares the field, written beside it in the group `field`
  (`path: "field"`, the layout ngff-zarr's docs give for a field next to the image it displaces);
- `bad_field_ras.ome.zarr`: converted against images oriented RAS-like (`left-to-right`, `posterior-to-anterior`):
  ngff-zarr itself cannot place it without those images, so a reader given the field alone refuses it.

`field_reference.json` holds, per field, what ngff-zarr's `ngff_displacement_field_to_itk_transform` reads back as an
ITK transform (size, origin, spacing, direction, the vectors i fastest, in the store's numbers) and the millimetres per
unit warpbench applies (1, or 0.001 for micrometres), so the expected LPS mm vectors are `vectors * mm`.

Run (from the repository root, in a venv with ngff-zarr 0.50.0, zarr 3.1.6, itk 5.4.7, numpy):

    python data-scripts/ngff_field_fixtures.py [--out tests/data/ngff]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import itk
import ngff_zarr as nz
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHAPE_ZYX = (6, 5, 4)
SPACING = (1.5, 2.0, 2.5)
ORIGIN = (10.0, -20.0, 30.0)


def itk_field(ras: bool = False) -> "itk.Image":
    """A smooth field whose three components differ at every voxel, ITK order [z][y][x][c]; its grid RAS-like with
    `ras`."""
    z, y, x = np.indices(SHAPE_ZYX, dtype=np.float32)
    vectors = np.stack([0.5 + 0.25 * x - 0.1 * z, -1.0 + 0.3 * y + 0.05 * x * y, 0.75 - 0.2 * z + 0.1 * x], axis=-1)
    image = itk.image_from_array(np.ascontiguousarray(vectors.astype(np.float32)), is_vector=True)
    image.SetSpacing(SPACING)
    image.SetOrigin(ORIGIN)
    if ras:
        image.SetDirection(itk.matrix_from_array(np.diag([-1.0, -1.0, 1.0])))
    return image


def frame_image(units: str | None, ras: bool) -> nz.NgffImage:
    """An image in the field's frame (LPS, or RAS-like with `ras`) to convert the field against."""
    image = itk.image_from_array(np.zeros(SHAPE_ZYX, np.float32))
    image.SetSpacing(SPACING)
    image.SetOrigin(ORIGIN)
    if ras:
        image.SetDirection(itk.matrix_from_array(np.diag([-1.0, -1.0, 1.0])))
    ngff = nz.itk_image_to_ngff_image(image, add_anatomical_orientation=True)
    if units:
        ngff.axes_units = {d: units for d in ("x", "y", "z")}
    return ngff


def write_field(store: Path, fixed: nz.NgffImage | None, ras: bool = False) -> None:
    transform, field = nz.itk_displacement_field_to_ngff_transform(
        itk_field(ras), ["z", "y", "x"], path="0", fixed=fixed, moving=fixed
    )
    multiscales = nz.declare_field_transform(nz.to_multiscales(field, scale_factors=[]))
    nz.to_ngff_zarr(str(store), multiscales, version="0.6")


def write_image_with_field(store: Path) -> None:
    """The image (zeros in the field's grid), then the field in its group `field`, declared on the image."""
    fixed = frame_image("millimeter", ras=False)
    transform, field = nz.itk_displacement_field_to_ngff_transform(
        itk_field(), ["z", "y", "x"], path="field", fixed=fixed, moving=fixed
    )
    image = nz.to_multiscales(fixed, scale_factors=[])
    physical = image.metadata.coordinateSystems[-1].name if getattr(image.metadata, "coordinateSystems", None) else None
    image = nz.declare_field_transform(
        image, path="field", input_system=physical, output_system=physical
    ) if physical else nz.declare_field_transform(image, path="field")
    nz.to_ngff_zarr(str(store), image, version="0.6")
    nz.to_ngff_zarr(str(store / "field"), nz.to_multiscales(field, scale_factors=[]), version="0.6")


def itk_view(store: Path, field_group: str = "") -> dict:
    """What ngff-zarr reads back as an ITK displacement field transform, without the two images."""
    multiscales = nz.from_ngff_zarr(str(store), validate=True)
    transform = next(t for t in multiscales.metadata.coordinateTransformations if t.type == "displacements")
    field = multiscales if not field_group else nz.from_ngff_zarr(str(store / field_group), validate=True)
    (entry,) = nz.ngff_displacement_field_to_itk_transform(transform, field, ["z", "y", "x"])
    fixed = np.asarray(entry.fixedParameters)
    size = fixed[:3].astype(int)
    vectors = np.asarray(entry.parameters, dtype=np.float64).reshape(size[2], size[1], size[0], 3)
    return {
        "size": size.tolist(),
        "origin": fixed[3:6].tolist(),
        "spacing": fixed[6:9].tolist(),
        "direction": fixed[9:18].reshape(3, 3).tolist(),
        # i fastest, as warpbench stores a field.
        "vectors": vectors.reshape(-1, 3).tolist(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "tests" / "data" / "ngff")
    args = ap.parse_args()
    out = args.out
    stores = {
        "field_plain": (lambda p: write_field(p, None), 1.0, ""),
        "field_lps_mm": (lambda p: write_field(p, frame_image("millimeter", ras=False)), 1.0, ""),
        "field_um": (lambda p: write_field(p, frame_image("micrometer", ras=False)), 0.001, ""),
        "image_with_field": (write_image_with_field, 1.0, "field"),
    }
    reference = {"ngff_zarr": nz.__version__, "itk": itk.__version__, "fields": []}
    for name, (make, mm, group) in stores.items():
        store = out / f"{name}.ome.zarr"
        shutil.rmtree(store, ignore_errors=True)
        make(store)
        reference["fields"].append({"name": name, "mm_per_unit": mm, **itk_view(store, group)})
    bad = out / "bad_field_ras.ome.zarr"
    shutil.rmtree(bad, ignore_errors=True)
    write_field(bad, frame_image("millimeter", ras=True), ras=True)
    try:
        itk_view(bad)
        raise SystemExit("ngff-zarr placed the RAS-oriented field without its images")
    except ValueError as e:
        reference["refused"] = {"name": "bad_field_ras", "ngff_zarr_says": str(e).split(";")[0]}
    (out / "field_reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    print(f"wrote {len(stores) + 1} fields and field_reference.json to {out}")


if __name__ == "__main__":
    main()
