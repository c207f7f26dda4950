"""MNI tag point files (``.tag``) and MNI transform files (``.xfm``), the landmarks and transforms of MINC's
``register``, ``tagtoxfm``, ``minctracc`` and ``mincresample``, against VTK 9.7.1 and SimpleITK 2.5.7.

- ``write_landmarks(NAME.tag)`` and ``landmarks --out NAME.tag`` write a file ``vtkMNITagPointReader`` reads to the same
  points (volume 1 the fixed ones, volume 2 the moving ones, RAS) and names;
- ``transform --format minc``, ``Warp.to_xfm`` and ``align --out-tfm NAME.xfm`` write a linear transform
  ``vtkMNITransformReader`` and SimpleITK read as the map from the moving volume's world to the fixed one's (RAS): it
  takes each moving landmark onto its fixed partner, and is the inverse of the ITK ``.tfm`` of the same run;
- ``--initial NAME.xfm`` and ``fit(initial=NAME.xfm)`` read it back as that warp.

Needs VTK, SimpleITK and numpy, and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

vtk_minc = pytest.importorskip("vtkmodules.vtkIOMINC")
sitk = pytest.importorskip("SimpleITK")

import warpbench as wb  # noqa: E402
from conftest import DATA, T1, run_cli  # noqa: E402

FLIP = np.array([-1.0, -1.0, 1.0])


def vtk_tags(path: Path) -> tuple[int, list[np.ndarray], list[str]]:
    reader = vtk_minc.vtkMNITagPointReader()
    reader.SetFileName(str(path))
    reader.Update()
    volumes = reader.GetNumberOfVolumes()
    points = []
    for v in range(volumes):
        p = reader.GetPoints(v)
        points.append(np.array([p.GetPoint(i) for i in range(p.GetNumberOfPoints())]))
    labels = reader.GetLabelText()
    names = [labels.GetValue(i) for i in range(labels.GetNumberOfValues())] if labels is not None else []
    return volumes, points, names


def exact_affine_pairs() -> wb.Pairs:
    """Pairs an affine map takes exactly (moving = A · fixed + t, LPS), so any linear fit recovers it."""
    rng = np.random.default_rng(11)
    fixed = rng.uniform(-40.0, 40.0, (9, 3))
    a = np.array([[0.97, 0.08, -0.03], [-0.06, 1.04, 0.05], [0.02, -0.04, 0.99]])
    moving = fixed @ a.T + np.array([4.5, -7.25, 2.0])
    return wb.Pairs(moving, fixed, [f"p{i}" for i in range(9)])


def test_vtk_reads_the_tag_files_warpbench_writes(tmp_path: Path) -> None:
    pairs = exact_affine_pairs()
    out = tmp_path / "pairs.tag"
    wb.write_landmarks(out, pairs)
    volumes, points, names = vtk_tags(out)
    assert volumes == 2 and names == pairs.names
    # VTK holds float32 points; volume 1 is the fixed one, in RAS.
    np.testing.assert_allclose(points[0], pairs.fixed * FLIP, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(points[1], pairs.moving * FLIP, rtol=1e-6, atol=1e-5)
    back = wb.read_landmarks(out)
    np.testing.assert_array_equal(back.fixed, pairs.fixed)
    np.testing.assert_array_equal(back.moving, pairs.moving)
    # The command line converts to and from it, and reads VTK's and register's files.
    csv = tmp_path / "pairs.csv"
    run_cli("landmarks", DATA / "mni" / "hand_written.tag", "--out", csv, "--quiet")
    again = tmp_path / "again.tag"
    run_cli("landmarks", csv, "--out", again, "--quiet")
    _, theirs, their_names = vtk_tags(DATA / "mni" / "hand_written.tag")
    _, ours, our_names = vtk_tags(again)
    assert our_names == their_names
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)
    done = run_cli("landmarks", DATA / "mni" / "one_volume.tag", "--json", expect=2)
    assert "one_volume.tag" in done.stderr and "one volume" in done.stderr


def vtk_map(path: Path, points: np.ndarray) -> np.ndarray:
    reader = vtk_minc.vtkMNITransformReader()
    reader.SetFileName(str(path))
    reader.Update()
    t = reader.GetTransform()
    return np.array([t.TransformPoint(tuple(p)) for p in points])


def test_the_xfm_maps_moving_landmarks_onto_fixed_ones(tmp_path: Path) -> None:
    pairs = exact_affine_pairs()
    fixed_ras, moving_ras = pairs.fixed * FLIP, pairs.moving * FLIP
    warp = wb.fit(pairs, "affine")
    out = tmp_path / "moving_to_fixed.xfm"
    warp.to_xfm(out)
    np.testing.assert_allclose(vtk_map(out, moving_ras), fixed_ras, rtol=0, atol=1e-6)
    itk = sitk.ReadTransform(str(out))  # MINC's numbers as they are: RAS in, RAS out
    np.testing.assert_allclose([itk.TransformPoint(tuple(p)) for p in moving_ras], fixed_ras, rtol=0, atol=1e-6)
    # Read back as a starting transform: the same warp.
    again = wb.fit(wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3))), "affine", initial=out)
    np.testing.assert_allclose(again.pullback(pairs.fixed), pairs.moving, rtol=0, atol=1e-6)
    # The command line writes the same file (but for the comment), and refuses a deformable warp or another name.
    csv = tmp_path / "pairs.csv"
    wb.write_landmarks(csv, pairs)
    volume = T1
    base = ["transform", "--fixed", volume, "--moving", volume, "--landmarks", csv, "--quiet"]
    cli = tmp_path / "cli.xfm"
    run_cli(*base, "--method", "affine", "--format", "minc", "--out", cli)
    assert cli.read_text().splitlines()[3:] == out.read_text().splitlines()[3:]
    done = run_cli(*base, "--method", "tps", "--format", "minc", "--out", tmp_path / "tps.xfm", expect=2)
    assert "tps.xfm" in done.stderr and "holds an affine only" in done.stderr
    done = run_cli(*base, "--method", "affine", "--format", "minc", "--out", tmp_path / "x.tfm", expect=2)
    assert "x.tfm" in done.stderr and "name it .xfm" in done.stderr
    described = run_cli("info", cli, "--json").stdout
    assert '"format": "mni_xfm"' in described and '"read_as": "starting_transform"' in described
    done = run_cli(*base, "--method", "affine", "--out", tmp_path / "itk.xfm", expect=2)
    assert "itk.xfm" in done.stderr and "MNI (MINC) transform file" in done.stderr


def test_align_writes_its_result_as_an_xfm(tmp_path: Path) -> None:
    from test_ants_mat_sitk import pair  # noqa: PLC0415

    fixed, moving = pair(tmp_path)
    tfm, xfm = tmp_path / "start.tfm", tmp_path / "start.xfm"
    for out in (tfm, xfm):
        run_cli("align", "--fixed", fixed, "--moving", moving, "--seed", "7", "--quiet", "--out-tfm", out)
    pullback = sitk.ReadTransform(str(tfm))  # fixed → moving, LPS
    points = np.random.default_rng(1).uniform(-30.0, 30.0, (8, 3))
    moved = np.array([pullback.TransformPoint(tuple(p)) for p in points])
    assert np.abs(moved - points).max() > 0.5, "the alignment moves points"
    # The .xfm is its inverse, in RAS: it takes each moved point back.
    np.testing.assert_allclose(vtk_map(xfm, moved * FLIP), points * FLIP, rtol=0, atol=1e-6)
    # A grid transform (nonlinear) is refused as a starting transform, naming it.
    none = tmp_path / "none.csv"
    none.write_text("")
    done = run_cli("transform", "--fixed", fixed, "--moving", moving, "--landmarks", none, "--initial",
                   DATA / "mni" / "grid.xfm", "--out", tmp_path / "x.tfm", expect=2)
    assert "grid.xfm" in done.stderr and "Grid_Transform" in done.stderr


def test_a_grid_transform_is_a_displacement_field_on_its_grid(tmp_path: Path) -> None:
    """An ``.xfm`` of one ``Grid_Transform`` reads as the field of its MINC grid: the forward map (the moving volume's
    world to the fixed one's), or the pull-back with ``Invert_Flag``; SimpleITK reads the same vectors (RAS numbers)."""
    path = DATA / "mni" / "grid_itk.xfm"
    field = wb.read_field(path)
    assert (field.source, field.direction, field.shape) == ("minc", "forward", (6, 5, 4))
    theirs = sitk.DisplacementFieldTransform(sitk.ReadTransform(str(path))).GetDisplacementField()
    ras = sitk.GetArrayFromImage(theirs).transpose(2, 1, 0, 3)  # (i, j, k, 3), MINC's RAS numbers
    np.testing.assert_array_equal(field.array * np.array([-1.0, -1.0, 1.0], dtype=np.float32), ras.astype(np.float32))
    assert wb.read_field(DATA / "mni" / "grid_inverted.xfm").direction == "pullback"
    # warp --field takes it (inverting the forward map) and info describes it.
    info = run_cli("info", path).stdout
    assert "(minc)" in info and "forward" in info
    done = run_cli("warp", "--fixed", T1, "--moving", T1, "--field", DATA / "mni" / "tps.xfm", "--out",
                   tmp_path / "w.nii.gz", expect=2)
    assert "tps.xfm" in done.stderr and "Thin_Plate_Spline_Transform" in done.stderr


@pytest.mark.parametrize("direction", ["pullback", "forward"])
def test_field_format_minc_writes_a_grid_transform_libminc_reads(tmp_path: Path, direction: str) -> None:
    """``field --format minc`` writes an ``.xfm`` and its MINC 2 grid beside it: warpbench reads back the same vectors
    as the ITK flavour of the same field, and libminc (SimpleITK) reads the grid to them (RAS numbers); the forward
    map as it is, the pull-back with ``Invert_Flag``."""
    pairs = exact_affine_pairs()
    csv = tmp_path / "pairs.csv"
    wb.write_landmarks(csv, pairs)
    base = ["field", "--fixed", T1, "--moving", T1, "--landmarks", csv, "--method", "tps", "--direction", direction,
            "--quiet"]
    out, nii = tmp_path / "u.xfm", tmp_path / "u.nii.gz"
    run_cli(*base, "--format", "minc", "--out", out)
    run_cli(*base, "--format", "itk", "--out", nii)
    ours, ref = wb.read_field(out), wb.read_field(nii)
    assert (ours.source, ours.direction) == ("minc", direction)
    assert ("Invert_Flag = True;" in out.read_text()) == (direction == "pullback")
    np.testing.assert_array_equal(ours.array, ref.array)
    np.testing.assert_allclose(ours.lps_from_index, ref.lps_from_index, rtol=0, atol=1e-9)
    grid = sitk.ReadImage(str(tmp_path / "u_grid_0.mnc"))
    assert grid.GetNumberOfComponentsPerPixel() == 3
    theirs = sitk.GetArrayFromImage(grid).transpose(2, 1, 0, 3)
    np.testing.assert_array_equal(theirs.astype(np.float32), ours.array * np.array([-1, -1, 1], dtype=np.float32))
    done = run_cli(*base, "--format", "minc", "--out", tmp_path / "u.nii.gz", "--force", expect=2)
    assert "u.nii.gz" in done.stderr and ".xfm" in done.stderr
