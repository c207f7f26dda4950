"""MINC volumes (``.mnc``: the MNI's minc-toolkit, CIVET, BrainWeb), read and written, against nibabel and SimpleITK.

Two independent readers check warpbench here:

- nibabel 5.4.2 (``Minc1Image``, ``Minc2Image``): every file of ``tests/data/minc/`` (nibabel's own test files, files
  SimpleITK wrote and edits of them, a MINC 1 file scipy wrote) reads to nibabel's real values and affine (in LPS);
- SimpleITK 2.5.7, whose ``MINCImageIO`` is libminc 2.4, MINC's own library: what ``Volume.write`` and
  ``warp --out NAME.mnc`` write, it reads to the same values at the same places. It takes MINC's world coordinates as
  they are (RAS numbers, with no flip to ITK's LPS), so its physical points are compared with RAS ones.

Needs nibabel, SimpleITK and numpy, and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")
sitk = pytest.importorskip("SimpleITK")

import warpbench as wb  # noqa: E402
from conftest import DATA, run_cli  # noqa: E402

MINC_DATA = DATA / "minc"
FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])
REFERENCE = {f["file"]: f for f in json.loads((MINC_DATA / "reference.json").read_text())["files"]}
FILES = sorted(MINC_DATA / name for name in REFERENCE)


def frames_of(img, dimorder: list[str]) -> list[np.ndarray]:
    """nibabel's real values of each frame, as warpbench's (i, j, k) arrays: the file's spatial axes reversed."""
    data = np.asarray(img.get_fdata())
    if "time" in dimorder:
        t = dimorder.index("time")
        frames = [np.take(data, f, axis=t) for f in range(data.shape[t])]
    else:
        frames = [data]
    return [f.transpose(2, 1, 0) for f in frames]


def ras_of(volume: wb.Volume) -> np.ndarray:
    return FLIP @ volume.lps_from_index


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_a_minc_file_reads_as_nibabel_reads_it(path: Path) -> None:
    theirs = nib.load(path)
    frames = frames_of(theirs, REFERENCE[path.name]["dimorder"])
    # nibabel's affine follows the file's spatial axes, slowest first: warpbench's i is its third column.
    affine = theirs.affine.copy()
    affine[:3, :3] = theirs.affine[:3, 2::-1]
    for f, want in enumerate(frames):
        ours = wb.read_volume(path, frame=f if len(frames) > 1 else None)
        np.testing.assert_allclose(ras_of(ours), affine, rtol=0, atol=1e-9)
        # Real values: nibabel's doubles, which warpbench holds as float32 (or exactly, as integers).
        np.testing.assert_array_equal(ours.array.astype(np.float32), want.astype(np.float32))
    if len(frames) > 1:
        with pytest.raises(ValueError, match=rf"4-D file with {len(frames)} frames: pass frame=N"):
            wb.read_volume(path)


def sitk_ras_points(img) -> tuple[np.ndarray, np.ndarray]:
    """Every voxel's world point as SimpleITK places it (MINC's RAS numbers), and its value, in index order."""
    size = img.GetSize()
    index = np.stack(np.meshgrid(*[np.arange(n) for n in size], indexing="ij"), -1).reshape(-1, 3)
    direction = np.array(img.GetDirection()).reshape(3, 3)
    points = np.array(img.GetOrigin()) + index @ (direction * np.array(img.GetSpacing())).T
    values = sitk.GetArrayFromImage(img).transpose(2, 1, 0).reshape(-1)
    return points, values


def assert_libminc_reads(path: Path, volume: wb.Volume) -> None:
    """SimpleITK's libminc reads `path` to `volume`'s values at `volume`'s voxel centres."""
    img = sitk.ReadImage(str(path))
    assert img.GetNumberOfComponentsPerPixel() == 1
    points, values = sitk_ras_points(img)
    ijk = (np.linalg.inv(ras_of(volume)) @ np.c_[points, np.ones(len(points))].T)[:3].T
    voxel = np.rint(ijk).astype(int)
    np.testing.assert_allclose(ijk, voxel, rtol=0, atol=1e-6)
    assert len(values) == volume.array.size
    np.testing.assert_array_equal(values, volume.array[voxel[:, 0], voxel[:, 1], voxel[:, 2]])


SOURCES = [
    DATA / "mgh" / "oblique_u8.mgh",
    DATA / "mgh" / "oblique_i16.mgh",
    DATA / "mgh" / "oblique_u16.mgh",
    DATA / "mgh" / "oblique_f32.mgh",
    DATA / "mgh" / "conformed_lia_u8.mgh",
    MINC_DATA / "small.mnc",
]


@pytest.mark.parametrize("source", SOURCES, ids=lambda p: p.name)
def test_libminc_and_nibabel_read_what_warpbench_writes(tmp_path: Path, source: Path) -> None:
    volume = wb.read_volume(source)
    out = tmp_path / "written.mnc"
    volume.write(out)
    theirs = nib.load(out)
    assert isinstance(theirs, nib.Minc2Image)
    (data,) = frames_of(theirs, [])
    np.testing.assert_array_equal(data.astype(volume.array.dtype), volume.array)
    assert theirs.get_data_dtype().newbyteorder("=") == volume.array.dtype.newbyteorder("=")
    assert_libminc_reads(out, volume)
    assert wb.read_volume(out).lps_from_index == pytest.approx(volume.lps_from_index, abs=1e-9)


def test_warp_writes_a_warped_volume_libminc_reads(tmp_path: Path) -> None:
    """``warp --out NAME.mnc`` onto a MINC grid: libminc reads the fixed grid and the moving volume's sample type."""
    fixed, moving = MINC_DATA / "oblique_i16.mnc", DATA / "mgh" / "oblique_i16.mgh"
    identity = tmp_path / "identity.tfm"
    identity.write_text("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
                        "Parameters: 1 0 0 0 1 0 0 0 1 0 0 0\nFixedParameters: 0 0 0\n")
    none = tmp_path / "none.csv"
    none.write_text("")
    out = tmp_path / "warped.mnc"
    run_cli("warp", "--fixed", fixed, "--moving", moving, "--initial", identity, "--landmarks", none, "--out", out,
            "--quiet")
    warped = wb.read_volume(out)
    assert warped.array.dtype == np.int16
    np.testing.assert_allclose(warped.lps_from_index, wb.read_volume(fixed).lps_from_index, rtol=0, atol=1e-9)
    assert_libminc_reads(out, warped)


def test_bad_files_are_refused_with_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mnc"
    bad.write_text("not a volume\n")
    done = run_cli("info", bad, expect=2)
    assert "bad.mnc" in done.stderr and "MINC" in done.stderr
    with pytest.raises(ValueError, match="bad.mnc"):
        wb.read_volume(bad)
