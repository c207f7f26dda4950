"""MetaImage (.mha, .mhd + .raw) between warpbench and SimpleITK, both ways.

- warpbench writes: `warpbench warp` with identity landmarks (affine, nearest neighbour) resamples a volume onto its
  own grid, so its output is the input; written as `.mha` and `.mhd`, SimpleITK reads it back to the input's array
  (numpy's k-j-i) and origin, spacing and direction.
- SimpleITK writes: `.mha` (compressed or not) and `.mhd` of each pixel type; `warpbench info --json` reports the same
  dims, lps_from_index = [D diag(spacing) | origin] and voxels (their sha256 in warpbench's sample type, i fastest).

Needs SimpleITK and numpy, and the CLI binary (`conftest.py`: `WARPBENCH_BIN`, default
`<repo>/target/debug/warpbench`).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

sitk = pytest.importorskip("SimpleITK")

from conftest import run_cli as warpbench  # noqa: E402


def direction() -> tuple:
    """An oblique direction: 20 deg about S, then 10 deg about L (row-major, as SimpleITK takes it)."""
    a, b = math.radians(20.0), math.radians(10.0)
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    return tuple((rz @ rx).flatten())


SPACING = (0.9, 1.25, 2.0)
ORIGIN = (-12.5, 30.25, -7.0)


def volume(dtype, shape=(9, 10, 11)) -> "sitk.Image":
    """A (k, j, i) = `shape` volume of `dtype`, different at every voxel, on the oblique grid."""
    k, j, i = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    values = (i * 7 + j * 13 + k * 29) % 200 - 60
    img = sitk.GetImageFromArray(values.astype(dtype))
    img.SetSpacing(SPACING)
    img.SetOrigin(ORIGIN)
    img.SetDirection(direction())
    return img


def identity_pairs(path: Path, img) -> None:
    """Five BigWarp pairs with both points at the same (non-coplanar) voxel centres of `img`."""
    rows = []
    for n, idx in enumerate([(1, 1, 1), (7, 1, 2), (1, 8, 3), (2, 2, 7), (8, 7, 6)]):
        p = img.TransformIndexToPhysicalPoint(idx)
        rows.append(",".join([f'"Pt-{n}"', '"true"'] + [f'"{v!r}"' for v in p] * 2))
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize("name", ["out.mha", "out.mhd"])
@pytest.mark.parametrize("dtype", [np.int16, np.float32])
def test_simpleitk_reads_what_warpbench_writes(tmp_path: Path, name: str, dtype) -> None:
    img = volume(dtype)
    source = tmp_path / "in.mha"
    sitk.WriteImage(img, str(source), True)
    pairs = tmp_path / "identity.csv"
    identity_pairs(pairs, img)
    out = tmp_path / name
    float_flag = ["--float"] if dtype == np.float32 else []
    warpbench(
        "warp", "--fixed", source, "--moving", source, "--landmarks", pairs, "--method", "affine",
        "--interp", "nearest", "--backend", "cpu", *float_flag, "--quiet", "--out", out,
    )
    if name.endswith(".mhd"):
        assert (tmp_path / "out.raw").is_file()
    back = sitk.ReadImage(str(out))
    assert back.GetPixelID() == img.GetPixelID()
    assert back.GetSize() == img.GetSize()
    np.testing.assert_array_equal(sitk.GetArrayFromImage(back), sitk.GetArrayFromImage(img))
    np.testing.assert_allclose(back.GetOrigin(), img.GetOrigin(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.GetSpacing(), img.GetSpacing(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.GetDirection(), img.GetDirection(), rtol=0, atol=1e-12)


# SimpleITK's pixel type, warpbench's sample type (docs/formats.md) and its little-endian numpy dtype.
TYPES = [
    (np.uint8, "u8", "<u1"),
    (np.int8, "i16", "<i2"),
    (np.int16, "i16", "<i2"),
    (np.uint16, "u16", "<u2"),
    (np.int32, "f32", "<f4"),
    (np.float32, "f32", "<f4"),
    (np.float64, "f32", "<f4"),
]


@pytest.mark.parametrize("dtype,ours,little", TYPES)
@pytest.mark.parametrize("name,compress", [("in.mha", True), ("in_raw.mha", False), ("in.mhd", False)])
def test_warpbench_reads_what_simpleitk_writes(tmp_path: Path, dtype, ours: str, little: str, name: str,
                                               compress: bool) -> None:
    arr_kji = sitk.GetArrayFromImage(volume(dtype))
    if dtype in (np.uint8, np.uint16):
        arr_kji = (arr_kji.astype(np.int64) + 60).astype(dtype)
    img = sitk.GetImageFromArray(arr_kji)
    img.SetSpacing(SPACING)
    img.SetOrigin(ORIGIN)
    img.SetDirection(direction())
    path = tmp_path / name
    sitk.WriteImage(img, str(path), compress)
    info = json.loads(warpbench("info", "--json", "--quiet", path).stdout)
    assert info["format"] == "metaimage"
    assert info["geometry_source"]["kind"] == "metaimage"
    assert info["dims"] == list(img.GetSize())
    assert info["dtype"] == ours
    d = np.array(img.GetDirection()).reshape(3, 3)
    want = np.eye(4)
    want[:3, :3] = d @ np.diag(img.GetSpacing())
    want[:3, 3] = img.GetOrigin()
    np.testing.assert_allclose(np.array(info["lps_from_index"]), want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(info["spacing_mm"], img.GetSpacing(), rtol=0, atol=1e-12)
    # The voxels, i fastest, in warpbench's sample type (f64 and i32 rounded to f32, i8 widened to i16).
    samples = np.transpose(sitk.GetArrayFromImage(sitk.ReadImage(str(path))))
    digest = hashlib.sha256(np.asarray(samples, little).tobytes(order="F")).hexdigest()
    assert info["voxel_sha256"] == digest
