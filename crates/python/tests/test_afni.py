"""AFNI's matrix file (``.aff12.1D``: ``3dAllineate -1Dmatrix_save``, ``-1Dmatrix_apply``), against nitransforms.

AFNI's documentation defines the row of twelve numbers as the base-to-source matrix in DICOM coordinates (x to the
left, y to the back): warpbench's pull-back with the fixed volume as the base. nitransforms 25.1.0
(``nitransforms.io.afni``) is the independent writer and reader here, between the volumes of ``tests/data/fsl/``
that are not oblique (LAS and LPS grids); AFNI works on oblique datasets in coordinates of its own, so a volume
that is oblique is refused:

- a matrix nitransforms writes for a known transform is read by ``--initial`` and ``fit(initial=)`` as the transform
  nitransforms reads from it (1e-9 mm);
- ``transform --format afni`` and ``Warp.to_afni`` write the same file, which nitransforms reads as warpbench's warp;
- an oblique volume, a file of several matrices (3dvolreg's, one per sub-brick) and a deformable warp are refused.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

nitl = pytest.importorskip("nitransforms.linear")

import warpbench as wb  # noqa: E402
from conftest import DATA, run_cli  # noqa: E402
from test_fsl import apply_lps, inside, pair_rows  # noqa: E402

FSL_DATA = DATA / "fsl"


def known_transform() -> np.ndarray:
    return np.array(json.loads((FSL_DATA / "reference.json").read_text())["known_ras"])


def mapped(tmp_path: Path, args: list, points_lps: np.ndarray) -> np.ndarray:
    targets, out = tmp_path / "targets.csv", tmp_path / "mapped.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points_lps.tolist()))
    run_cli("points", *args, "--from", "fixed", "--in", targets, "--out", out, "--quiet", "--force")
    return np.array([[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()])


def test_initial_reads_an_afni_matrix_as_nitransforms_does(tmp_path: Path) -> None:
    fixed, moving = FSL_DATA / "las.nii.gz", FSL_DATA / "lps.nii.gz"
    afni = tmp_path / "mr_to_ct.aff12.1D"
    nitl.Affine(known_transform(), reference=str(fixed)).to_filename(afni, fmt="afni", moving=str(moving))
    assert afni.read_text().startswith("#")
    theirs = nitl.load(afni, fmt="afni", reference=str(fixed), moving=str(moving))
    points = np.random.default_rng(3).uniform(-40.0, 40.0, (12, 3))
    none = tmp_path / "none.csv"
    none.write_text("")
    args = ["--fixed", fixed, "--moving", moving, "--initial", afni, "--landmarks", none]
    # nitransforms writes %g (six digits): both read the same numbers from the file.
    np.testing.assert_allclose(mapped(tmp_path, args, points), apply_lps(theirs, points), rtol=0, atol=1e-9)
    empty = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(empty, initial=afni, fixed=wb.read_volume(fixed), moving=wb.read_volume(moving))
    np.testing.assert_allclose(warp.pullback(points), apply_lps(theirs, points), rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=r"mr_to_ct\.aff12\.1D: an AFNI matrix .* give fixed= .* and moving="):
        wb.fit(empty, initial=afni)


@pytest.mark.parametrize("method", ["start", "rigid"])
def test_transform_writes_the_afni_matrix_nitransforms_reads(tmp_path: Path, method: str) -> None:
    fixed, moving = FSL_DATA / "las.nii.gz", FSL_DATA / "lps.nii.gz"
    start = tmp_path / "start.aff12.1D"
    nitl.Affine(known_transform(), reference=str(fixed)).to_filename(start, fmt="afni", moving=str(moving))
    pairs = tmp_path / "pairs.csv"
    pairs.write_text(pair_rows("las", "lps", np.random.default_rng(8)) if method == "rigid" else "")
    args = ["--fixed", fixed, "--moving", moving, "--initial", start, "--landmarks", pairs]
    args += ["--method", "rigid"] if method == "rigid" else []
    out = tmp_path / "written.aff12.1D"
    run_cli("transform", *args, "--format", "afni", "--out", out, "--quiet")
    theirs = nitl.load(out, fmt="afni", reference=str(fixed), moving=str(moving))
    points = np.random.default_rng(5).uniform(-30.0, 30.0, (10, 3))
    # The shortest decimals that read back: the same doubles.
    np.testing.assert_allclose(apply_lps(theirs, points), mapped(tmp_path, args, points), rtol=0, atol=1e-9)
    lines = out.read_text().splitlines()
    assert len(lines) == 2 and lines[0].startswith("#") and len(lines[1].split()) == 12
    landmarks = wb.read_landmarks(pairs) if method == "rigid" else wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    volumes = {"fixed": wb.read_volume(fixed), "moving": wb.read_volume(moving)}
    warp = wb.fit(landmarks, "rigid" if method == "rigid" else "tps", initial=start, **volumes)
    warp.to_afni(tmp_path / "python.aff12.1D")
    assert (tmp_path / "python.aff12.1D").read_bytes() == out.read_bytes()


def test_align_writes_its_result_for_afni_as_its_tfm(tmp_path: Path) -> None:
    """``align --out-tfm NAME.aff12.1D`` writes the alignment as AFNI's matrix file: nitransforms reads it to the
    transform SimpleITK reads from the ``.tfm`` of the same seeded run. An oblique volume is refused before
    aligning, and an ITK writer given a ``.1D`` name refuses it."""
    sitk = pytest.importorskip("SimpleITK")
    from test_ants_mat_sitk import pair  # noqa: PLC0415

    fixed, moving = pair(tmp_path)
    tfm, afni = tmp_path / "start.tfm", tmp_path / "start.aff12.1D"
    for out in (tfm, afni):
        run_cli("align", "--fixed", fixed, "--moving", moving, "--seed", "7", "--quiet", "--out-tfm", out)
    theirs = nitl.load(afni, fmt="afni", reference=str(fixed), moving=str(moving))
    itk = sitk.ReadTransform(str(tfm))
    points = np.random.default_rng(1).uniform(-30.0, 30.0, (8, 3))
    want = np.array([itk.TransformPoint(tuple(p)) for p in points])
    assert np.abs(want - points).max() > 0.5, "the alignment moves points"
    # The shortest decimals that read back (AFNI's file) against the .tfm's 17 significant digits.
    np.testing.assert_allclose(apply_lps(theirs, points), want, rtol=0, atol=1e-9)
    oblique = FSL_DATA / "oblique.nii.gz"
    done = run_cli("align", "--fixed", oblique, "--moving", moving, "--quiet", "--out-tfm", tmp_path / "o.aff12.1D",
                   expect=2)
    assert "o.aff12.1D" in done.stderr and "fixed volume is oblique" in done.stderr
    none = tmp_path / "none.csv"
    none.write_text("")
    done = run_cli("transform", "--fixed", fixed, "--moving", moving, "--initial", tfm, "--landmarks", none,
                   "--out", tmp_path / "itk.1D", "--quiet", expect=2)
    assert "itk.1D" in done.stderr and "AFNI's matrix file, not an ITK transform file" in done.stderr


def test_afni_refusals(tmp_path: Path) -> None:
    las, lps, oblique = (FSL_DATA / f"{n}.nii.gz" for n in ("las", "lps", "oblique"))
    afni = tmp_path / "start.aff12.1D"
    afni.write_text("# 3dAllineate matrices (DICOM-to-DICOM, row-by-row):\n1 0 0 2 0 1 0 0 0 0 1 0\n")
    none = tmp_path / "none.csv"
    none.write_text("")
    targets = tmp_path / "targets.csv"
    targets.write_text("0,0,0\n")
    base = ["points", "--landmarks", none, "--from", "fixed", "--in", targets, "--out", tmp_path / "o.csv"]
    done = run_cli(*base, "--fixed", oblique, "--moving", lps, "--initial", afni, expect=2)
    assert "start.aff12.1D" in done.stderr and "fixed volume is oblique" in done.stderr
    # 3dvolreg's file: one matrix per sub-brick, here 60 rows as its documentation shows them (6.6 kB: more than the
    # head a file is told by).
    volreg = tmp_path / "volreg.aff12.1D"
    row = (" 1 0.000906864 -0.000222938 -0.0564219 -0.000908728 0.999963 -0.00850925 -0.660097 0.000215214"
           " 0.00850945 0.999964 0.579968\n")
    volreg.write_text("# 3dvolreg matrices (DICOM-to-DICOM, row-by-row):\n" + row * 60)
    assert volreg.stat().st_size > 4096
    done = run_cli(*base, "--fixed", las, "--moving", lps, "--initial", volreg, expect=2)
    assert "volreg.aff12.1D" in done.stderr and "60 matrices" in done.stderr
    # A TPS has no AFNI matrix; nor does an oblique pair.
    pairs = tmp_path / "pairs.csv"
    pairs.write_text(pair_rows("las", "lps", np.random.default_rng(2)))
    out = tmp_path / "tps.aff12.1D"
    t = ["transform", "--moving", lps, "--landmarks", pairs, "--format", "afni", "--out", out, "--quiet"]
    done = run_cli(*t, "--fixed", las, expect=2)
    assert "tps.aff12.1D" in done.stderr and "AFNI's matrix file holds an affine only" in done.stderr
    pairs.write_text(pair_rows("oblique", "lps", np.random.default_rng(2)))
    done = run_cli(*t, "--fixed", oblique, "--method", "affine", expect=2)
    assert "fixed volume is oblique" in done.stderr and not out.exists()
