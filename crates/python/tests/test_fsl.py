"""FSL's FLIRT matrix (``flirt -omat``), against nitransforms' reading and writing of it.

A FLIRT matrix maps the input image's FSL coordinates (voxel indices scaled by the voxel size, the first axis
reversed for an image whose voxel-to-world matrix has a positive determinant) to the reference image's, so it means
something only with the two images. nitransforms 25.1.0 (``nitransforms.io.fsl``, checked there against FSL's own
tools) is the independent reader and writer here:

- a matrix nitransforms writes for a known transform between two volumes is read by ``--initial`` (and Python's
  ``fit(initial=, fixed=, moving=)``) as the transform nitransforms reads from it, mapping points within 1e-9 mm, for
  volumes of either handedness, oblique or not, with their own voxel sizes (``tests/data/fsl/``);
- ``transform --format fsl`` writes a matrix that nitransforms reads as warpbench's own pull-back;
- without the volumes, for a deformable warp and under a name of another format, it is refused.

Needs nitransforms (and its scipy and h5py), nibabel and numpy, and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")
nitl = pytest.importorskip("nitransforms.linear")

import warpbench as wb  # noqa: E402
from conftest import DATA, run_cli  # noqa: E402


# The volumes of `tests/data/fsl/` (`data-scripts/fsl_flirt_nitransforms.py`), 4 x 5 x 3 voxels, whose grids matter:
# oblique and neurological (det > 0), radiological (LAS, det < 0), LPS (det > 0, both first axes reversed), and an
# oblique radiological one, each with its own voxel sizes.
FSL_DATA = DATA / "fsl"


def volume(tmp_path: Path, name: str) -> Path:
    """The fixture volume `name` (`tmp_path` is where a test's own files go)."""
    del tmp_path
    return FSL_DATA / f"{name}.nii.gz"


def inside(name: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """`n` LPS points inside the volume `name`, its voxel centres' box."""
    image = nib.load(FSL_DATA / f"{name}.nii.gz")
    ijk = rng.uniform(0.0, np.array(image.shape) - 1.0, (n, 3))
    ras = (image.affine[:3, :3] @ ijk.T).T + image.affine[:3, 3]
    return ras * [-1.0, -1.0, 1.0]


def pair_rows(fixed: str, moving: str, rng: np.random.Generator) -> str:
    """Six BigWarp CSV rows pairing points inside `moving` with points inside `fixed`."""
    rows = []
    for n, (p, q) in enumerate(zip(inside(moving, 6, rng), inside(fixed, 6, rng))):
        rows.append(f'"Pt-{n}","true",' + ",".join(f'"{float(v)!r}"' for v in (*p, *q)))
    return "\n".join(rows) + "\n"


def known_transform() -> np.ndarray:
    """A pull-back in RAS (reference points to moving points), as nitransforms holds a transform: the one the
    fixtures' matrices were written from."""
    return np.array(json.loads((FSL_DATA / "reference.json").read_text())["known_ras"])


FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])  # RAS ↔ LPS


def apply_lps(theirs, points_lps: np.ndarray) -> np.ndarray:
    """nitransforms' transform (a RAS matrix) applied to LPS points, in doubles: its own ``map`` rounds the points
    to float32 first."""
    lps = FLIP @ theirs.matrix @ FLIP
    return (lps[:3, :3] @ points_lps.T).T + lps[:3, 3]


def mapped_by_warpbench(tmp_path: Path, fixed: Path, moving: Path, initial: Path, points_lps: np.ndarray) -> np.ndarray:
    targets, out, none = tmp_path / "targets.csv", tmp_path / "mapped.csv", tmp_path / "none.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points_lps.tolist()))
    none.write_text("")
    run_cli("points", "--fixed", fixed, "--moving", moving, "--initial", initial, "--landmarks", none,
            "--from", "fixed", "--in", targets, "--out", out, "--quiet")
    return np.array([[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()])


@pytest.mark.parametrize("fixed_grid,moving_grid", [("oblique", "las"), ("lps", "oblique_las"), ("las", "lps")])
def test_initial_reads_a_flirt_matrix_as_nitransforms_does(tmp_path: Path, fixed_grid: str, moving_grid: str) -> None:
    fixed, moving = volume(tmp_path, fixed_grid), volume(tmp_path, moving_grid)
    flirt = tmp_path / "mr_to_ct.mat"
    nitl.Affine(known_transform(), reference=str(fixed)).to_filename(flirt, fmt="fsl", moving=str(moving))
    theirs = nitl.load(flirt, fmt="fsl", reference=str(fixed), moving=str(moving))
    rng = np.random.default_rng(4)
    points_lps = rng.uniform(-40.0, 40.0, (12, 3))
    want_lps = apply_lps(theirs, points_lps)
    np.testing.assert_allclose(mapped_by_warpbench(tmp_path, fixed, moving, flirt, points_lps), want_lps, rtol=0,
                               atol=1e-9)
    # The file's 8 decimals hold the known transform to ~1e-6 of its numbers.
    want_known = (FLIP @ known_transform() @ FLIP)[:3] @ np.c_[points_lps, np.ones(len(points_lps))].T
    np.testing.assert_allclose(want_lps, want_known.T, rtol=0, atol=1e-4)

    none = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(none, initial=flirt, fixed=wb.read_volume(fixed), moving=wb.read_volume(moving))
    np.testing.assert_allclose(warp.pullback(points_lps), want_lps, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=r"mr_to_ct\.mat: an FSL FLIRT matrix .* give fixed= .* and moving="):
        wb.fit(none, initial=flirt)


@pytest.mark.parametrize("method", ["start", "affine"])
def test_transform_writes_the_flirt_matrix_nitransforms_reads(tmp_path: Path, method: str) -> None:
    fixed, moving = volume(tmp_path, "oblique"), volume(tmp_path, "las")
    start = tmp_path / "start.mat"
    nitl.Affine(known_transform(), reference=str(fixed)).to_filename(start, fmt="fsl", moving=str(moving))
    pairs = tmp_path / "pairs.csv"
    if method == "affine":
        pairs.write_text(pair_rows("oblique", "las", np.random.default_rng(9)))
        args = ["--landmarks", pairs, "--method", "affine"]
    else:
        pairs.write_text("")
        args = ["--landmarks", pairs]
    out = tmp_path / "written.mat"
    common = ["--fixed", fixed, "--moving", moving, "--initial", start, *args]
    run_cli("transform", *common, "--format", "fsl", "--out", out, "--quiet")
    theirs = nitl.load(out, fmt="fsl", reference=str(fixed), moving=str(moving))
    rng = np.random.default_rng(5)
    points_lps = rng.uniform(-30.0, 30.0, (10, 3))
    # warpbench's own pull-back of the same inputs.
    targets, mapped = tmp_path / "t.csv", tmp_path / "m.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points_lps.tolist()))
    run_cli("points", *common, "--from", "fixed", "--in", targets, "--out", mapped, "--quiet")
    ours = np.array([[float(v) for v in line.split(",")[:3]] for line in mapped.read_text().splitlines()])
    got = apply_lps(theirs, points_lps)
    # Twelve decimals in the file.
    np.testing.assert_allclose(got, ours, rtol=0, atol=1e-8)
    lines = out.read_text().splitlines()
    assert len(lines) == 4 and lines[3].split() == ["0.000000000000"] * 3 + ["1.000000000000"]
    # Python writes the same file from the same fit.
    landmarks = wb.read_landmarks(pairs) if method == "affine" else wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    volumes = {"fixed": wb.read_volume(fixed), "moving": wb.read_volume(moving)}
    warp = wb.fit(landmarks, "affine" if method == "affine" else "tps", initial=start, **volumes)
    from_python = tmp_path / "python.mat"
    warp.to_fsl(from_python)
    assert from_python.read_bytes() == out.read_bytes()
    rng = np.random.default_rng(6)
    bare = wb.fit(wb.Pairs(inside("las", 5, rng), inside("oblique", 5, rng)), "affine")
    with pytest.raises(ValueError, match="bare.mat: .* fit the warp with fixed= and moving="):
        bare.to_fsl(tmp_path / "bare.mat")


def test_flirt_refusals(tmp_path: Path) -> None:
    fixed, moving = volume(tmp_path, "oblique"), volume(tmp_path, "las")
    pairs = tmp_path / "pairs.csv"
    pairs.write_text(pair_rows("oblique", "las", np.random.default_rng(2)))
    base = ["transform", "--fixed", fixed, "--moving", moving, "--landmarks", pairs, "--format", "fsl", "--quiet"]
    done = run_cli(*base, "--out", tmp_path / "tps.mat", expect=2)
    assert "tps.mat" in done.stderr and "FLIRT matrix holds an affine only" in done.stderr
    assert not (tmp_path / "tps.mat").exists()
    done = run_cli(*base, "--method", "affine", "--out", tmp_path / "x.h5", expect=2)
    assert "x.h5" in done.stderr and "name it as `flirt -omat` does" in done.stderr
    # A text file of numbers that is not a FLIRT matrix is refused by --initial, naming it and the line.
    bad = tmp_path / "bad.mat"
    bad.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 2 1\n")
    done = run_cli("points", "--fixed", fixed, "--moving", moving, "--initial", bad, "--landmarks", pairs,
                   "--from", "fixed", "--in", pairs, "--out", tmp_path / "o.csv", expect=2)
    assert "bad.mat" in done.stderr and "0 0 0 1" in done.stderr
    # Given as a field, it is named for what it is.
    good = tmp_path / "good.mat"
    good.write_text("1 0 0 2\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    done = run_cli("warp", "--fixed", fixed, "--moving", moving, "--field", good, "--out", tmp_path / "w.nii.gz",
                   expect=2)
    assert "good.mat" in done.stderr and "FLIRT matrix" in done.stderr and "--initial" in done.stderr
