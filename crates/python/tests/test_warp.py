"""fit and Warp against the CLI on the same inputs (the same numbers, the same bytes), and against oracles."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import warpbench as wb
from conftest import PAIRS, T1, cli_json, run_cli

PAIR_ARGS = ["--fixed", T1, "--moving", T1, "--landmarks", PAIRS]


@pytest.fixture(scope="module")
def head():
    return wb.read_volume(T1)


@pytest.fixture(scope="module")
def pairs():
    return wb.read_landmarks(PAIRS)


@pytest.fixture(scope="module")
def warp(head, pairs):
    return wb.fit(pairs, "tps", fixed=head, moving=head)


def points_csv(path, points):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z"])
        for p in points:
            w.writerow([repr(float(c)) for c in p])


def read_points(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return np.array([[float(c) for c in r[:3]] for r in rows[1:]])


QUERIES = np.array([[1.0, 2.0, 3.0], [-25.5, 10.0, 20.0], [40.0, -60.0, 30.0], [0.0, -20.0, 60.0]])


@pytest.mark.parametrize("side", ["fixed", "moving"])
def test_points_equal_the_cli(tmp_path, warp, side):
    points_csv(tmp_path / "in.csv", QUERIES)
    run_cli("points", *PAIR_ARGS, "--from", side, "--in", tmp_path / "in.csv", "--out", tmp_path / "out.csv",
            "--quiet")
    expected = read_points(tmp_path / "out.csv")
    got = warp.pullback(QUERIES) if side == "fixed" else warp.forward(QUERIES)
    # The CLI writes shortest round-trip decimals: equal to the last bit.
    np.testing.assert_array_equal(got, expected)


def test_the_pairs_are_honoured(warp, pairs):
    # A TPS with λ = 0 interpolates: u(q_i) = p_i and d(p_i) = q_i.
    np.testing.assert_allclose(warp.pullback(pairs.fixed), pairs.moving, atol=1e-6)
    np.testing.assert_allclose(warp.forward(pairs.moving), pairs.fixed, atol=1e-6)


@pytest.mark.parametrize(
    "fmt,name", [("itk", "f.nii.gz"), ("ants", "f.nii.gz"), ("nrrd", "f.nrrd"), ("metaimage", "f.mha")]
)
def test_field_writes_the_bytes_the_cli_writes(tmp_path, warp, head, fmt, name):
    (tmp_path / "cli").mkdir()
    run_cli("field", *PAIR_ARGS, "--format", fmt, "--out", tmp_path / "cli" / name, "--quiet")
    array = warp.field(path=tmp_path / name, format=fmt)
    assert (tmp_path / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()
    # The array holds u(x) − x at every voxel centre, LPS.
    assert array.shape == (*head.shape, 3)
    ijk = np.array([[0, 0, 0], [45, 54, 45], [90, 108, 90], [10, 90, 3]])
    x = (head.lps_from_index @ np.c_[ijk, np.ones(len(ijk))].T).T[:, :3]
    np.testing.assert_allclose(array[tuple(ijk.T)], warp.pullback(x) - x, atol=1e-4)


def test_resample_writes_the_bytes_the_cli_writes(tmp_path, warp, head):
    for interp in ["linear", "nearest"]:
        run_cli("warp", *PAIR_ARGS, "--backend", "cpu", "--interp", interp, "--out", tmp_path / f"cli-{interp}.nii",
                "--quiet")
        warp.resample(head, interpolation=interp).write(tmp_path / f"py-{interp}.nii")
        assert (tmp_path / f"py-{interp}.nii").read_bytes() == (tmp_path / f"cli-{interp}.nii").read_bytes()


def test_to_itk_tfm_writes_the_bytes_the_cli_writes(tmp_path, warp):
    run_cli("transform", *PAIR_ARGS, "--out", tmp_path / "cli.tfm", "--quiet")
    warp.to_itk_tfm(tmp_path / "py.tfm")
    assert (tmp_path / "py.tfm").read_bytes() == (tmp_path / "cli.tfm").read_bytes()


def test_to_elastix_writes_the_bytes_the_cli_writes(tmp_path, warp):
    run_cli("transform", *PAIR_ARGS, "--format", "elastix", "--out", tmp_path / "cli.txt", "--quiet")
    warp.to_elastix(tmp_path / "py.txt")
    assert (tmp_path / "py.txt").read_bytes() == (tmp_path / "cli.txt").read_bytes()
    assert '(Transform "SplineKernelTransform")' in (tmp_path / "py.txt").read_text()


def test_leave_one_out_equals_refits_without_each_pair(warp, pairs):
    loo = warp.leave_one_out()
    assert loo["rows"] == list(range(1, len(pairs) + 1))
    np.testing.assert_allclose(loo["residual_mm"], 0.0, atol=1e-6)
    # The oracle: fit again without pair i and measure how far u sends q_i from p_i.
    for i in range(len(pairs)):
        keep = np.arange(len(pairs)) != i
        rest = wb.Pairs(pairs.moving[keep], pairs.fixed[keep])
        refit = wb.fit(rest, "tps")
        error = np.linalg.norm(refit.pullback(pairs.fixed[i]) - pairs.moving[i])
        assert loo["leave_one_out_mm"][i] == pytest.approx(error, rel=1e-6, abs=1e-6)
    assert loo["mean_mm"] == pytest.approx(np.mean(loo["leave_one_out_mm"]))


def test_folding_agrees_with_finite_differences_of_the_pullback(warp):
    f = warp.folding(n=16)
    assert f["points"] == 16**3 and not f["folds"]
    x = np.array(f["min_at"])
    h = 1e-3
    jac = np.stack([(warp.pullback(x + h * e) - warp.pullback(x - h * e))[0] / (2 * h) for e in np.eye(3)], axis=1)
    assert np.linalg.det(jac) == pytest.approx(f["min_det"], rel=1e-5)


def test_stiffness_auto_chooses_the_clis_lambda(tmp_path, head, pairs):
    summary = cli_json("field", *PAIR_ARGS, "--stiffness", "auto", "--out", tmp_path / "f.nii.gz")
    warp = wb.fit(pairs, stiffness="auto", fixed=head, moving=head)
    assert warp.method == summary["method"]


def test_initial_transform_is_under_the_landmarks(tmp_path, head, pairs):
    # A translation by (3, -2, 1) mm as ITK writes it (fixed points to moving points).
    tfm = tmp_path / "t.tfm"
    tfm.write_text(
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
        "Parameters: 1 0 0 0 1 0 0 0 1 3 -2 1\nFixedParameters: 0 0 0\n"
    )
    # Below the affine's pairs the transform alone is the warp.
    few = wb.Pairs(pairs.moving[:2], pairs.fixed[:2])
    alone = wb.fit(few, "affine", initial=tfm)
    np.testing.assert_allclose(alone.pullback(QUERIES), QUERIES + [3, -2, 1], atol=1e-9)
    points_csv(tmp_path / "in.csv", QUERIES)
    run_cli("points", *PAIR_ARGS, "--initial", tfm, "--from", "fixed", "--in", tmp_path / "in.csv", "--out",
            tmp_path / "out.csv", "--quiet")
    on_start = wb.fit(pairs, "tps", initial=tfm, fixed=head, moving=head)
    np.testing.assert_array_equal(on_start.pullback(QUERIES), read_points(tmp_path / "out.csv"))


def test_bad_pairs_are_refused_with_the_landmark_named(head, pairs):
    moved = wb.Pairs(pairs.moving.copy(), pairs.fixed.copy(), names=list(pairs.names), source="my pairs")
    moved.fixed[2] = [500.0, 0.0, 0.0]
    with pytest.raises(ValueError) as e:
        wb.fit(moved, fixed=head, moving=head)
    assert "my pairs: landmark 3 (Pt-2) is outside the fixed volume" in str(e.value)
    with pytest.raises(ValueError, match="needs at least 4"):
        wb.fit(wb.Pairs(pairs.moving[:3], pairs.fixed[:3]), "tps")
    with pytest.raises(ValueError, match="method="):
        wb.fit(pairs, "spline")
    with pytest.raises(ValueError, match="stiffness"):
        wb.fit(pairs, stiffness=-1.0)
    with pytest.raises(ValueError, match="stiffness"):
        wb.fit(pairs, "affine", stiffness="auto")


def test_landmarks_read_as_the_cli_lists_them_and_write_the_same_bytes(tmp_path, pairs):
    listing = cli_json("landmarks", PAIRS)
    rows = listing["pairs"]
    assert listing["format"] == pairs.format
    assert [r["name"] for r in rows] == pairs.names
    np.testing.assert_array_equal(np.array([r["moving"] for r in rows]), pairs.moving)
    np.testing.assert_array_equal(np.array([r["fixed"] for r in rows]), pairs.fixed)
    for name in ["p.json", "p.csv"]:
        run_cli("landmarks", PAIRS, "--out", tmp_path / f"cli-{name}", "--quiet")
        wb.write_landmarks(tmp_path / name, pairs)
        assert (tmp_path / name).read_bytes() == (tmp_path / f"cli-{name}").read_bytes()
    again = wb.read_landmarks(tmp_path / "p.json")
    np.testing.assert_array_equal(again.moving, pairs.moving)
    with pytest.raises(OSError):
        wb.read_landmarks(tmp_path / "none.csv")
