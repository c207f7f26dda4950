"""OME-Zarr images (NGFF 0.4 to 0.6: napari, BigWarp's Zarr exports, ngff-zarr, ``itk.imwrite(img, "x.ome.zarr")``)
read through Python.

``tests/data/ngff/reference.json`` holds what zarr-python 3.1 and ngff-zarr 0.50 read from each fixture
(``data-scripts/ngff_fixtures.py``): the values, hashed in warpbench's order, and ngff-zarr's placement of the grid
(voxel 0 at the x, y and z translations, RFC-4 orientations as directions, LPS) in mm. ``read_volume`` gives the
same values and grid, frames of a 4-D image one at a time, and refuses the bad images with a ``ValueError`` that names
the folder.

Needs numpy (``conftest.py``).
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA

NGFF = DATA / "ngff"
FILES = json.loads((NGFF / "reference.json").read_text())["files"]
GOOD = [f for f in FILES if f["refuse"] is None]
BAD = [f for f in FILES if f["refuse"] is not None]


def f32_sha256(array: np.ndarray) -> str:
    """The values as little-endian float32, i fastest: the reference's ``sha256_f32``."""
    return hashlib.sha256(np.asarray(array, dtype="<f4").tobytes(order="F")).hexdigest()


@pytest.mark.parametrize("entry", GOOD, ids=lambda f: f["name"])
def test_an_ome_zarr_image_reads_to_the_reference(entry: dict) -> None:
    path = NGFF / f"{entry['name']}.ome.zarr"
    frames = entry["frames"] or 1
    if frames > 1:
        with pytest.raises(ValueError, match=rf"4-D file with {frames} frames"):
            wb.read_volume(path)
    for frame, want in enumerate(entry["values"]):
        ours = wb.read_volume(path, frame=frame if frames > 1 else None)
        np.testing.assert_allclose(ours.lps_from_index, entry["spec"]["lps_from_index_mm_ngff_zarr"], rtol=0, atol=1e-12)
        assert f32_sha256(ours.array) == want["sha256_f32"]
        assert float(ours.array.min()) == pytest.approx(want["min"], rel=1e-6)
        assert float(ours.array.max()) == pytest.approx(want["max"], rel=1e-6)
        assert ours.header["geometry_source"]["kind"] == "ome_zarr"


@pytest.mark.parametrize("entry", BAD, ids=lambda f: f["name"])
def test_a_bad_ome_zarr_image_is_refused_naming_the_folder(entry: dict) -> None:
    path = NGFF / f"{entry['name']}.ome.zarr"
    with pytest.raises(ValueError, match=rf"{entry['name']}\.ome\.zarr.*{entry['refuse']}"):
        wb.read_volume(path)
