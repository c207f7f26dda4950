"""OME-Zarr 0.6 displacement fields (RFC-5's ``displacements``) through Python.

``tests/data/ngff/field_reference.json`` holds what ngff-zarr 0.50, the reference implementation, reads back from each
field it wrote (``data-scripts/ngff_field_fixtures.py``) as an ITK transform: its grid and its vectors, LPS, in the
store's units. ``read_field`` gives the same in mm (a micrometre is 0.001 mm), with ``source`` ``"ngff"`` and a
warning for each assumption. What ``Warp.field(path="x.ome.zarr")`` writes is read here by zarr-python and placed by
hand from its metadata: the components along z, y, x (S, P, L) at the voxel the scale and translation name, equal to
the array ``field`` returns.

Needs numpy and zarr (``.ci/run`` installs them).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr

import warpbench as wb
from conftest import DATA, PAIRS, T1

NGFF = DATA / "ngff"
REFERENCE = json.loads((NGFF / "field_reference.json").read_text())


@pytest.mark.parametrize("entry", REFERENCE["fields"], ids=lambda f: f["name"])
def test_a_field_reads_to_what_ngff_zarr_gives_itk(entry: dict) -> None:
    field = wb.read_field(NGFF / f"{entry['name']}.ome.zarr")
    mm = entry["mm_per_unit"]
    assert (field.source, field.direction) == ("ngff", None)
    assert list(field.shape) == entry["size"]
    lps = np.eye(4)
    lps[:3, :3] = np.array(entry["direction"]) * np.array(entry["spacing"]) * mm
    lps[:3, 3] = np.array(entry["origin"]) * mm
    np.testing.assert_allclose(field.lps_from_index, lps, rtol=0, atol=1e-12)
    vectors = np.array(entry["vectors"]).reshape(*entry["size"][::-1], 3).transpose(2, 1, 0, 3) * mm
    np.testing.assert_allclose(field.array, vectors, rtol=1e-6, atol=1e-9)
    if entry["name"] == "field_plain":
        assert any("taken as mm" in w for w in field.warnings), field.warnings
    else:
        assert field.warnings == ()


def test_a_field_the_store_cannot_place_is_a_value_error_naming_it() -> None:
    with pytest.raises(ValueError, match=r"bad_field_ras\.ome\.zarr.*x left-to-right"):
        wb.read_field(NGFF / "bad_field_ras.ome.zarr")
    with pytest.raises(ValueError, match=r"field_plain\.ome\.zarr.*a displacement field"):
        wb.read_volume(NGFF / "field_plain.ome.zarr")


def test_a_written_field_is_where_its_metadata_places_it(tmp_path) -> None:
    head = wb.read_volume(T1)
    warp = wb.fit(wb.read_landmarks(PAIRS), "tps", fixed=head, moving=head)
    out = tmp_path / "u.ome.zarr"
    sampled = warp.field(path=out)  # the name picks the flavour
    group = zarr.open_group(out, mode="r")
    ome = group.attrs["ome"]
    assert ome["version"] == "0.6"
    (multiscale,) = ome["multiscales"]
    (transform,) = multiscale["coordinateTransformations"]
    assert transform["type"] == "displacements" and transform["interpolation"] == "linear"
    (dataset,) = multiscale["datasets"]
    assert transform["path"] == dataset["path"]
    systems = {s["name"]: s["axes"] for s in multiscale["coordinateSystems"]}
    assert [a["name"] for a in systems[transform["output"]["name"]]] == ["z", "y", "x"]
    intrinsic = systems[dataset["coordinateTransformations"][0]["output"]["name"]]
    assert [(a["name"], a["type"]) for a in intrinsic] == [("c", "displacement"), ("z", "space"), ("y", "space"), ("x", "space")]
    assert [a["orientation"]["value"] for a in intrinsic[1:]] == ["inferior-to-superior", "anterior-to-posterior", "right-to-left"]
    assert all(a["unit"] == "millimeter" for a in intrinsic[1:])
    steps = dataset["coordinateTransformations"][0]["transformations"]
    scale, translation = np.array(steps[0]["scale"][1:]), np.array(steps[1]["translation"][1:])
    stored = group[dataset["path"]][...]  # (c, z, y, x): the S, P, L components
    assert stored.shape[0] == 3

    # Each voxel of the fixed grid: its LPS centre, (S, P, L) against the translation and scale, is an element index.
    ijk = np.indices(head.shape).reshape(3, -1)
    lps = head.lps_from_index[:3, :3] @ ijk + head.lps_from_index[:3, 3:4]
    index = (lps[::-1] - translation[:, None]) / scale[:, None]
    rounded = np.rint(index).astype(int)
    assert np.abs(index - rounded).max() < 1e-6
    z, y, x = rounded
    want = sampled[ijk[0], ijk[1], ijk[2]]
    for c, lps_axis in enumerate([2, 1, 0]):
        np.testing.assert_array_equal(stored[c, z, y, x], want[:, lps_axis])
    back = wb.read_field(out)
    assert back.source == "ngff" and back.warnings == ()
