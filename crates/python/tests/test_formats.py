"""The Python and ITK worlds' formats through the package: MetaImage volumes, elastix point sets as pairs,
transformix's output, ITK's and 3D Slicer's thin-plate-spline files as pairs, and the ANTs affine .mat as fit's initial transform (each checked against the CLI, and the
volumes against SimpleITK)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA, FIXED, PAIRS, T1, run_cli

sitk = pytest.importorskip("SimpleITK")


@pytest.mark.parametrize("name", ["v.mha", "v.mhd"])
def test_metaimage_round_trip_and_simpleitk_agrees(tmp_path, name):
    v = wb.read_volume(FIXED)
    v.write(tmp_path / name)
    back = wb.read_volume(tmp_path / name)
    np.testing.assert_array_equal(back.array, v.array)
    np.testing.assert_array_equal(back.lps_from_index, v.lps_from_index)
    image = sitk.ReadImage(str(tmp_path / name))
    np.testing.assert_array_equal(sitk.GetArrayViewFromImage(image).T, v.array)
    np.testing.assert_allclose(image.GetOrigin(), v.origin, atol=1e-12)
    np.testing.assert_allclose(image.GetSpacing(), v.spacing, atol=1e-12)
    np.testing.assert_allclose(np.array(image.GetDirection()).reshape(3, 3), v.direction, atol=1e-12)


def test_elastix_point_sets_are_pairs_as_on_the_command_line(tmp_path):
    pairs = wb.read_landmarks(PAIRS)
    wb.write_landmarks(tmp_path / "moving.txt", pairs, tmp_path / "fixed.txt")
    run_cli("landmarks", PAIRS, "--out-moving", tmp_path / "cli_moving.txt", "--out-fixed", tmp_path / "cli_fixed.txt",
            "--quiet")
    assert (tmp_path / "moving.txt").read_bytes() == (tmp_path / "cli_moving.txt").read_bytes()
    assert (tmp_path / "fixed.txt").read_bytes() == (tmp_path / "cli_fixed.txt").read_bytes()
    assert (tmp_path / "fixed.txt").read_text().splitlines()[:2] == ["point", "8"]
    back = wb.read_landmarks(tmp_path / "moving.txt", tmp_path / "fixed.txt")
    np.testing.assert_array_equal(back.moving, pairs.moving)
    np.testing.assert_array_equal(back.fixed, pairs.fixed)


def test_transformix_output_points_are_pairs(tmp_path):
    text = "".join(
        f"Point\t{i}\t; InputIndex = [ 0 0 0 ]\t; InputPoint = [ {q[0]:.6f} {q[1]:.6f} {q[2]:.6f} ]\t; "
        f"OutputIndexFixed = [ 0 0 0 ]\t; OutputPoint = [ {q[0] + 1:.6f} {q[1]:.6f} {q[2] - 2:.6f} ]\t; "
        f"Deformation = [ 1.000000 0.000000 -2.000000 ]\n"
        for i, q in enumerate([[1.0, 2.0, 3.0], [10.0, -5.0, 7.5]])
    )
    (tmp_path / "outputpoints.txt").write_text(text)
    pairs = wb.read_landmarks(tmp_path / "outputpoints.txt")
    np.testing.assert_allclose(pairs.fixed, [[1.0, 2.0, 3.0], [10.0, -5.0, 7.5]])
    np.testing.assert_allclose(pairs.moving, pairs.fixed + [1.0, 0.0, -2.0])


def test_a_slicer_spline_file_is_pairs_that_map_as_itk_does():
    """3D Slicer's thin-plate spline (data-scripts/slicer_transforms.py: ITK wrote it, under Slicer's inverse class), which
    SimpleITK cannot read, gives its landmarks as pairs; the spline fitted on them is ITK's spline from the moving to
    the fixed points, and ITK's own class gives the resampling spline."""
    reference = json.loads((DATA / "itk" / "slicer_tps_reference.json").read_text())
    for name in ["tps_slicer.h5", "tps_slicer.tfm"]:
        with pytest.raises(RuntimeError):
            sitk.ReadTransform(str(DATA / "itk" / name))
        pairs = wb.read_landmarks(DATA / "itk" / name)
        np.testing.assert_allclose(pairs.moving, reference["moving"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(pairs.fixed, reference["fixed"], rtol=0, atol=1e-12)
        warp = wb.fit(pairs, method="tps")
        np.testing.assert_allclose(warp.forward(reference["queries"]), reference["fixed_from_moving"], rtol=0, atol=1e-9)
    warp = wb.fit(wb.read_landmarks(DATA / "itk" / "tps_itk.h5"), method="tps")
    np.testing.assert_allclose(warp.pullback(reference["queries"]), reference["moving_from_fixed"], rtol=0, atol=1e-9)


def test_an_ants_mat_from_align_starts_a_fit_as_its_tfm_does(tmp_path):
    head = wb.read_volume(T1)
    moved = wb.Volume.from_array(head.array, head.lps_from_index @ np.array(
        [[1, 0, 0, 1.5], [0, 1, 0, -1.0], [0, 0, 1, 0.5], [0, 0, 0, 1.0]]))
    moved.write(tmp_path / "moved.nii.gz")
    options = dict(samples=3000, shrink=[4, 2], seed=2)
    mat = wb.align(T1, tmp_path / "moved.nii.gz", out_tfm=tmp_path / "a.mat", **options)
    tfm = wb.align(T1, tmp_path / "moved.nii.gz", out_tfm=tmp_path / "a.tfm", **options)
    np.testing.assert_array_equal(mat["moving_from_fixed"], tfm["moving_from_fixed"])
    assert sitk.ReadTransform(str(tmp_path / "a.mat")).GetParameters() == pytest.approx(
        sitk.ReadTransform(str(tmp_path / "a.tfm")).GetParameters(), abs=1e-12)
    pairs = wb.read_landmarks(PAIRS)
    few = wb.Pairs(pairs.moving[:2], pairs.fixed[:2])
    queries = pairs.fixed
    np.testing.assert_allclose(
        wb.fit(few, "affine", initial=tmp_path / "a.mat").pullback(queries),
        wb.fit(few, "affine", initial=tmp_path / "a.tfm").pullback(queries),
        atol=1e-9,
    )
