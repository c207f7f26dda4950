"""FreeSurfer's LTA (``.lta``: ``mri_robust_register``, ``bbregister``, ``lta_convert``, ``mri_vol2vol --lta``).

An LTA's matrix maps its src volume to its dst volume, and the file states both volumes' geometry; FreeSurfer's
programs write the moving volume (``--mov``) as src. The independent references here are FreeSurfer's own file
(``tests/data/lta/bold-to-t1w.lta``, lta_convert's RAS form of a bbregister result) and nitransforms 25.1.0
(``nitransforms.io.lta``), which reads an LTA as the pull-back M⁻¹:

- ``--initial`` (and ``fit(initial=, fixed=, moving=)``) read FreeSurfer's file between volumes on its src and dst
  grids as nitransforms reads it, and as its inverse with the volumes the other way round; volumes that are neither
  are refused;
- ``transform --format lta``, ``Warp.to_lta`` and ``align --out-tfm NAME.lta`` write files nitransforms reads as
  warpbench's warp, with the two volumes' geometry as nibabel states it;
- a deformable warp, and the names of other formats, are refused.

Needs nitransforms, nibabel and numpy, and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")
lta_io = pytest.importorskip("nitransforms.io.lta")

import warpbench as wb  # noqa: E402
from conftest import DATA, run_cli  # noqa: E402
from test_afni import mapped  # noqa: E402
from test_fsl import FSL_DATA, pair_rows  # noqa: E402

LTA_DATA = DATA / "lta"
FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])


def nitransforms_pullback(path: Path) -> np.ndarray:
    """The pull-back (fixed points to moving points) nitransforms reads from an LTA, in LPS."""
    return FLIP @ lta_io.FSLinearTransformArray.from_filename(path).to_ras()[0] @ FLIP


def apply(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    return (m[:3, :3] @ points.T).T + m[:3, 3]


def grid_volume(path: Path, geometry) -> Path:
    """A NIfTI volume of zeros on an LTA's volume geometry (what FreeSurfer noted of the volume it was made with)."""
    nib.Nifti1Image(np.zeros(tuple(int(n) for n in geometry["volume"]), np.uint8), geometry.as_affine()).to_filename(
        path)
    return path


def test_initial_reads_freesurfers_lta_either_way_round(tmp_path: Path) -> None:
    """bbregister's BOLD run (src, 64 x 64 x 34 oblique) to orig.mgz (dst, 256³): the fixed volume on dst's grid and
    the moving one on src's read it as nitransforms does; the other way round, as its inverse."""
    lta = LTA_DATA / "bold-to-t1w.lta"
    xform = lta_io.FSLinearTransformArray.from_filename(lta)["xforms"][0]
    bold, t1 = grid_volume(tmp_path / "bold.nii.gz", xform["src"]), grid_volume(tmp_path / "t1.nii.gz", xform["dst"])
    want = nitransforms_pullback(lta)
    points = np.random.default_rng(4).uniform(-60.0, 60.0, (10, 3))
    none = tmp_path / "none.csv"
    none.write_text("")
    # nitransforms reads the matrix in single precision: 6e-8 of its numbers.
    forward = mapped(tmp_path, ["--fixed", t1, "--moving", bold, "--initial", lta, "--landmarks", none], points)
    np.testing.assert_allclose(forward, apply(want, points), rtol=0, atol=2e-5)
    backward = mapped(tmp_path, ["--fixed", bold, "--moving", t1, "--initial", lta, "--landmarks", none], points)
    np.testing.assert_allclose(backward, apply(np.linalg.inv(want), points), rtol=0, atol=2e-5)
    empty = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(empty, initial=lta, fixed=wb.read_volume(t1), moving=wb.read_volume(bold))
    np.testing.assert_allclose(warp.pullback(points), forward, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=r"bold-to-t1w\.lta: a FreeSurfer LTA .* give fixed= .* and moving="):
        wb.fit(empty, initial=lta)
    # Neither volume is its src or dst: which way it maps is not guessed.
    other = FSL_DATA / "las.nii.gz"
    done = run_cli("points", "--fixed", other, "--moving", other, "--initial", lta, "--landmarks", none, "--from",
                   "fixed", "--in", tmp_path / "targets.csv", "--out", tmp_path / "o.csv", expect=2)
    assert "bold-to-t1w.lta" in done.stderr and "neither volume is the LTA's src" in done.stderr
    assert "uni_xform_masked.nii.gz" in done.stderr and "lta_convert" in done.stderr
    info = run_cli("info", lta).stdout
    assert "FreeSurfer LTA (lta), LINEAR_RAS_TO_RAS" in info and "orig.mgz" in info


@pytest.mark.parametrize("method", ["start", "rigid"])
def test_transform_writes_the_lta_nitransforms_reads(tmp_path: Path, method: str) -> None:
    fixed, moving = FSL_DATA / "oblique.nii.gz", FSL_DATA / "las.nii.gz"
    start = tmp_path / "start.tfm"
    start.write_text("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
                     "Parameters: 0.99 0.05 -0.02 -0.04 1.01 0.03 0.01 -0.02 0.98 3 -7.5 12.25\n"
                     "FixedParameters: 0 0 0\n")
    pairs = tmp_path / "pairs.csv"
    pairs.write_text(pair_rows("oblique", "las", np.random.default_rng(8)) if method == "rigid" else "")
    args = ["--fixed", fixed, "--moving", moving, "--initial", start, "--landmarks", pairs]
    args += ["--method", "rigid"] if method == "rigid" else []
    out = tmp_path / "written.lta"
    summary = run_cli("transform", *args, "--format", "lta", "--out", out, "--json", "--quiet").stdout
    assert '"map": "fixed_from_moving"' in summary and '"format": "lta"' in summary
    points = np.random.default_rng(5).uniform(-30.0, 30.0, (10, 3))
    np.testing.assert_allclose(apply(nitransforms_pullback(out), points), mapped(tmp_path, args, points), rtol=0,
                               atol=2e-5)
    xform = lta_io.FSLinearTransformArray.from_filename(out)["xforms"][0]
    for side, volume in (("src", moving), ("dst", fixed)):
        assert xform[side]["filename"] == str(volume)
        np.testing.assert_allclose(xform[side].as_affine(), nib.load(volume).affine, rtol=0, atol=1e-5)
    # The window's twin: Python's file is the same but for the comment naming the file itself.
    landmarks = wb.read_landmarks(pairs) if method == "rigid" else wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    volumes = {"fixed": wb.read_volume(fixed), "moving": wb.read_volume(moving)}
    warp = wb.fit(landmarks, "rigid" if method == "rigid" else "tps", initial=start, **volumes)
    warp.to_lta(tmp_path / "python.lta")
    ours = (tmp_path / "python.lta").read_text().splitlines()
    assert ours[0] == "# transform file python.lta"
    assert ours[1:] == out.read_text().splitlines()[1:]


def test_align_writes_its_result_as_an_lta_and_refusals(tmp_path: Path) -> None:
    sitk = pytest.importorskip("SimpleITK")
    from test_ants_mat_sitk import pair  # noqa: PLC0415

    fixed, moving = pair(tmp_path)
    tfm, lta = tmp_path / "start.tfm", tmp_path / "start.lta"
    for out in (tfm, lta):
        run_cli("align", "--fixed", fixed, "--moving", moving, "--seed", "7", "--quiet", "--out-tfm", out)
    itk = sitk.ReadTransform(str(tfm))
    points = np.random.default_rng(1).uniform(-30.0, 30.0, (8, 3))
    want = np.array([itk.TransformPoint(tuple(p)) for p in points])
    assert np.abs(want - points).max() > 0.5, "the alignment moves points"
    np.testing.assert_allclose(apply(nitransforms_pullback(lta), points), want, rtol=0, atol=2e-5)
    none = tmp_path / "none.csv"
    none.write_text("")
    base = ["transform", "--fixed", fixed, "--moving", moving, "--landmarks", none, "--quiet"]
    done = run_cli(*base, "--initial", tfm, "--out", tmp_path / "itk.lta", expect=2)
    assert "itk.lta" in done.stderr and "FreeSurfer's transform file, not an ITK one" in done.stderr
    done = run_cli(*base, "--initial", tfm, "--format", "lta", "--out", tmp_path / "x.tfm", expect=2)
    assert "x.tfm" in done.stderr and "name an LTA .lta" in done.stderr
    pairs = tmp_path / "pairs.csv"
    pairs.write_text(pair_rows("las", "lps", np.random.default_rng(2)))
    done = run_cli("transform", "--fixed", FSL_DATA / "las.nii.gz", "--moving", FSL_DATA / "lps.nii.gz", "--landmarks",
                   pairs, "--format", "lta", "--out", tmp_path / "tps.lta", expect=2)
    assert "tps.lta" in done.stderr and "FreeSurfer's LTA holds an affine only" in done.stderr
    assert not (tmp_path / "tps.lta").exists()
