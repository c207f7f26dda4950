"""OME-Zarr written by warpbench, read by zarr-python and placed by hand from the specification.

``Volume.write("x.ome.zarr")`` (and ``warpbench warp --out x.ome.zarr``) writes OME-Zarr 0.5: a Zarr v3 group whose
``ome`` attributes name one multiscale of axes z, y, x (space, millimetre, RFC-4 orientations) and one dataset with a
scale and a translation. Here zarr-python 3.1 reads the store, nibabel reads the source file, and each source voxel's
LPS centre (nibabel's RAS affine with x and y negated) is mapped through the written scale and translation, as
ngff-zarr places an image (voxel 0 at the x, y, z translations, the orientations as directions), to the array element
that must hold its value. With the orientations warpbench writes (+L, +P, +S) that is also where RFC-4's text puts
it. An oblique grid is refused with a ``ValueError`` that names the output.

Needs numpy, nibabel and zarr (``.ci/run`` installs them).
"""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest
import zarr

import warpbench as wb
from conftest import DATA, T1, run_cli

# A RAS NIfTI, FreeSurfer's LIA conformed volume, a MINC RAS volume with anisotropic steps.
SOURCES = [T1, DATA / "nifti" / "anatomical.nii", DATA / "mgh" / "conformed_lia_u8.mgz", DATA / "minc" / "small.mnc"]

DIRECTIONS = {
    "right-to-left": np.array([1.0, 0.0, 0.0]),
    "anterior-to-posterior": np.array([0.0, 1.0, 0.0]),
    "inferior-to-superior": np.array([0.0, 0.0, 1.0]),
}


def check_store(store, source) -> None:
    """Every voxel of the nibabel-read `source` is in zarr-python's array of `store` where the metadata places it."""
    group = zarr.open_group(store, mode="r")
    assert group.metadata.zarr_format == 3
    ome = group.attrs["ome"]
    assert ome["version"] == "0.5"
    (multiscale,) = ome["multiscales"]
    axes = multiscale["axes"]
    assert [a["name"] for a in axes] == ["z", "y", "x"]
    assert all(a["type"] == "space" and a["unit"] == "millimeter" for a in axes)
    assert all(a["orientation"]["type"] == "anatomical" for a in axes)
    (dataset,) = multiscale["datasets"]
    scale, translation = dataset["coordinateTransformations"]
    assert scale["type"] == "scale" and translation["type"] == "translation"
    array = group[dataset["path"]]
    assert array.metadata.dimension_names == ("z", "y", "x")
    stored = array[...]

    image = nib.load(source)
    values = np.asarray(image.dataobj)
    assert stored.dtype == values.dtype.newbyteorder("=") or (values.dtype == np.float64 and stored.dtype == np.float32)
    ijk = np.indices(values.shape[:3]).reshape(3, -1)
    ras = image.affine[:3, :3] @ ijk + image.affine[:3, 3:4]
    lps = ras * np.array([[-1.0], [-1.0], [1.0]])
    # Coordinate of each voxel along each axis (z, y, x): its LPS position along the axis's orientation, then index.
    index = []
    for a, axis in enumerate(axes):
        coordinate = DIRECTIONS[axis["orientation"]["value"]] @ lps
        index.append((coordinate - translation["translation"][a]) / scale["scale"][a])
    index = np.array(index)
    rounded = np.rint(index)
    assert np.abs(index - rounded).max() < 1e-4, "a voxel between the written ones"
    z, y, x = rounded.astype(int)
    assert (z >= 0).all() and (y >= 0).all() and (x >= 0).all()
    expected = values.reshape(-1)
    if stored.dtype.kind == "f":
        # nibabel scales MINC and MGH values in float64; warpbench in float32.
        np.testing.assert_allclose(stored[z, y, x], expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())
    else:
        np.testing.assert_array_equal(stored[z, y, x], expected)
    assert sorted(stored.shape) == sorted(values.shape[:3])


@pytest.mark.parametrize("source", SOURCES, ids=lambda p: p.name)
def test_a_written_store_holds_every_voxel_where_the_metadata_places_it(source, tmp_path) -> None:
    out = tmp_path / "out.ome.zarr"
    wb.read_volume(source).write(out)
    check_store(out, source)


def test_warp_writes_ome_zarr_too(tmp_path) -> None:
    out = tmp_path / "warped.ome.zarr"
    pairs = tmp_path / "pairs.csv"
    points = [(0, 0, 0), (40, 0, 0), (0, 40, 0), (0, 0, 40)]
    pairs.write_text("".join(f'"Pt-{n}","true","{x}","{y}","{z}","{x}","{y}","{z}"\n' for n, (x, y, z) in enumerate(points)))
    run_cli("warp", "--fixed", T1, "--moving", T1, "--landmarks", pairs, "--method", "affine", "--quiet", "--out", out)
    # Identity pairs give the input back.
    check_store(out, T1)


def test_an_oblique_grid_is_refused_naming_the_output(tmp_path) -> None:
    out = tmp_path / "oblique.ome.zarr"
    with pytest.raises(ValueError, match=r"oblique\.ome\.zarr.*oblique grid"):
        wb.read_volume(DATA / "minc" / "oblique_i16.mnc").write(out)
    assert list(tmp_path.iterdir()) == []
