"""FreeSurfer's MGH and MGZ volumes (``orig.mgz``, ``brain.mgz``, ``aseg.mgz``), read and written, against nibabel.

nibabel 5.4.2 (``nibabel.freesurfer.mghformat``) is the independent reader and writer here:

- every file of ``tests/data/mgh/`` that nibabel wrote (each MGH sample type on an oblique grid with unequal voxel
  sizes, two frames, FreeSurfer's conformed LIA orientation, tags after the data) reads to nibabel's voxels and to its
  affine (in LPS);
- what ``Volume.write``, ``warp --out NAME.mgz`` and ``register``'s siblings write as ``.mgh``/``.mgz`` nibabel reads
  back to the same voxels, sample type and grid.

Needs nibabel and numpy, and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")

import warpbench as wb  # noqa: E402
from conftest import DATA, run_cli  # noqa: E402

MGH_DATA = DATA / "mgh"
FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])
# The MGH files nibabel wrote; `no_ras_flag.mgh`, whose missing orientation nibabel and FreeSurfer fill in differently
# (docs/formats.md), is left to the Rust tests.
WRITTEN = sorted(p for p in MGH_DATA.glob("*.mg[hz]") if p.name != "no_ras_flag.mgh")


@pytest.mark.parametrize("path", WRITTEN, ids=lambda p: p.name)
def test_an_mgh_file_reads_as_nibabel_reads_it(path: Path) -> None:
    theirs = nib.load(path)
    data = np.asarray(theirs.dataobj)
    frames = [data[..., f] for f in range(data.shape[3])] if data.ndim == 4 else [data]
    for f, want in enumerate(frames):
        ours = wb.read_volume(path, frame=f if len(frames) > 1 else None)
        # The file's f32 fields, which nibabel partly combines in float32 (6e-8 of the ~10 mm entries).
        np.testing.assert_allclose(ours.lps_from_index, FLIP @ theirs.affine, rtol=0, atol=1e-5)
        # MGH's INT (i32) is read as float32, rounded to nearest as numpy rounds it.
        is_int32 = want.dtype.newbyteorder("=") == np.int32
        np.testing.assert_array_equal(ours.array, want.astype(np.float32) if is_int32 else want)
    if len(frames) > 1:
        with pytest.raises(ValueError, match=r"4-D file with 2 frames: pass frame=N"):
            wb.read_volume(path)


@pytest.mark.parametrize("name", ["oblique_u8", "oblique_i16", "oblique_u16", "oblique_f32", "conformed_lia_u8"])
@pytest.mark.parametrize("ext", ["mgh", "mgz"])
def test_nibabel_reads_what_warpbench_writes(tmp_path: Path, name: str, ext: str) -> None:
    volume = wb.read_volume(MGH_DATA / f"{name}.mgh")
    out = tmp_path / f"written.{ext}"
    volume.write(out)
    theirs = nib.load(out)
    assert isinstance(theirs, nib.MGHImage)
    data = np.asarray(theirs.dataobj)
    assert data.dtype.newbyteorder("=") == volume.array.dtype.newbyteorder("=")
    np.testing.assert_array_equal(data, volume.array)
    # The file holds the grid in float32 (voxel sizes, cosines, centre): 6e-8 of each.
    np.testing.assert_allclose(FLIP @ theirs.affine, volume.lps_from_index, rtol=0, atol=1e-5)


def test_warp_writes_a_warped_volume_freesurfer_reads(tmp_path: Path) -> None:
    """``warp --out NAME.mgz`` onto a conformed (LIA) grid: nibabel reads the fixed grid's affine and the moving
    volume's sample type; a name warpbench does not write is refused before anything is read."""
    fixed, moving = MGH_DATA / "conformed_lia_u8.mgz", MGH_DATA / "oblique_i16.mgz"
    identity = tmp_path / "identity.tfm"
    identity.write_text("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
                        "Parameters: 1 0 0 0 1 0 0 0 1 0 0 0\nFixedParameters: 0 0 0\n")
    none = tmp_path / "none.csv"
    none.write_text("")
    out = tmp_path / "warped.mgz"
    run_cli("warp", "--fixed", fixed, "--moving", moving, "--initial", identity, "--landmarks", none, "--out", out,
            "--quiet")
    theirs = nib.load(out)
    np.testing.assert_allclose(theirs.affine, nib.load(fixed).affine, rtol=0, atol=1e-5)
    assert theirs.shape == nib.load(fixed).shape and theirs.get_data_dtype().newbyteorder("=") == np.int16
    done = run_cli("warp", "--fixed", fixed, "--moving", moving, "--initial", identity, "--landmarks", none, "--out",
                   tmp_path / "warped.mgzz", expect=2)
    assert "warped.mgzz" in done.stderr and ".mgz, .mnc or .ome.zarr" in done.stderr
