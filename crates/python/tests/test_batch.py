"""A cohort on a Dask LocalCluster of 2 workers: per-case status, timing and accuracy; a bad case fails alone; a
rerun skips complete cases."""

from __future__ import annotations

import csv

import pytest

import warpbench as wb
from conftest import DATA, PAIRS, T1, run_cli

pytest.importorskip("dask.distributed")

from warpbench.batch import Case, run_cohort  # noqa: E402


def test_a_cohort_runs_case_by_case_and_a_rerun_skips_what_is_complete(tmp_path):
    pairs = wb.read_landmarks(PAIRS)
    bad = wb.Pairs(pairs.moving.copy(), pairs.fixed.copy(), names=list(pairs.names))
    bad.fixed[4] = [900.0, 0.0, 0.0]
    wb.write_landmarks(tmp_path / "bad.csv", bad)
    cases = [
        Case("s01", T1, T1, PAIRS, out=tmp_path / "out" / "s01.nii.gz", out_field=tmp_path / "out" / "s01_field.nii.gz"),
        Case("s02", T1, T1, PAIRS, out=tmp_path / "out" / "s02.nii.gz", method="affine"),
        Case("s03", T1, T1, tmp_path / "bad.csv", out=tmp_path / "out" / "s03.nii.gz"),
    ]
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, Client(
        cluster
    ) as client:
        first = run_cohort(cases, client=client, table=tmp_path / "results.csv")
        assert [r.status for r in first] == ["ok", "ok", "failed"]
        s01, s02, s03 = first
        assert s01.method == "tps" and s02.method == "affine" and s01.pairs == 8
        # The accuracy recorded is the fit's leave-one-out, as Warp.leave_one_out gives it.
        warp = wb.fit(pairs, fixed=wb.read_volume(T1), moving=wb.read_volume(T1))
        assert s01.leave_one_out_mm == pytest.approx(warp.leave_one_out()["mean_mm"])
        assert s01.min_det > 0 and s01.seconds > 0
        # The bad case's error names its file and the landmark (1-based); nothing was written for it.
        assert "bad.csv: landmark 5 (Pt-4) is outside the fixed volume" in s03.error
        assert not (tmp_path / "out" / "s03.nii.gz").exists()
        # The outputs are what the CLI writes for the same case.
        run_cli("warp", "--fixed", T1, "--moving", T1, "--landmarks", PAIRS, "--backend", "cpu", "--out",
                tmp_path / "cli.nii.gz", "--quiet")
        assert (tmp_path / "out" / "s01.nii.gz").read_bytes() == (tmp_path / "cli.nii.gz").read_bytes()
        with open(tmp_path / "results.csv") as f:
            table = list(csv.DictReader(f))
        assert [row["status"] for row in table] == ["ok", "ok", "failed"]

        stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "out").iterdir()}
        again = run_cohort(cases, client=client)
        assert [r.status for r in again] == ["skipped", "skipped", "failed"]
        assert again[0].leave_one_out_mm == s01.leave_one_out_mm
        assert {p: p.stat().st_mtime_ns for p in (tmp_path / "out").iterdir()} == stamps

        # A removed output makes its case run again.
        (tmp_path / "out" / "s02.nii.gz").unlink()
        third = run_cohort(cases, client=client)
        assert [r.status for r in third] == ["skipped", "ok", "failed"]


def test_case_names_must_differ(tmp_path):
    c = Case("same", T1, T1, PAIRS, out=tmp_path / "a.nii")
    with pytest.raises(ValueError, match="name"):
        run_cohort([c, c], client=object())


def test_a_case_corrects_another_tools_registration_as_the_cli_does(tmp_path):
    """``Case(initial_field=...)``: the landmarks fitted over another tool's result (SimpleITK's composite of an affine
    and a B-spline, ``tests/data/itk/tfm_composite.tfm``) give the volume ``warpbench warp --initial-field`` gives."""
    from warpbench.batch import run_case

    composite = DATA / "itk" / "tfm_composite.tfm"
    case = Case("s01", T1, T1, PAIRS, out=tmp_path / "s01.nii.gz", initial_field=composite)
    result = run_case(case)
    assert result.status == "ok", result.error
    assert "tfm_composite.tfm" in result.method
    run_cli("warp", "--fixed", T1, "--moving", T1, "--landmarks", PAIRS, "--initial-field", composite, "--backend",
            "cpu", "--out", tmp_path / "cli.nii.gz", "--quiet")
    assert (tmp_path / "s01.nii.gz").read_bytes() == (tmp_path / "cli.nii.gz").read_bytes()


def test_a_case_reads_the_frame_chosen_of_a_4d_file_as_the_cli_does(tmp_path):
    """``Case(moving_frame=N)``: the frame is read for the fit and the output, and passed to ``register``; a case
    without a choice fails alone, saying how to choose."""
    from warpbench.batch import run_case

    nib = pytest.importorskip("nibabel")
    np = pytest.importorskip("numpy")
    t1 = nib.load(str(T1))
    data = np.asanyarray(t1.dataobj).astype(np.float32)
    four_d = tmp_path / "two_frames.nii.gz"
    nib.save(nib.Nifti1Image(np.stack([data, data[::-1] * 0.5 + 7.0], axis=3), t1.affine), str(four_d))

    case = Case("s01", T1, four_d, PAIRS, out=tmp_path / "s01.nii.gz", moving_frame=1)
    assert case.parts() == {"moving_frame": 1}
    result = run_case(case)
    assert result.status == "ok", result.error
    run_cli("warp", "--fixed", T1, "--moving", four_d, "--moving-frame", "1", "--landmarks", PAIRS, "--backend",
            "cpu", "--out", tmp_path / "cli.nii.gz", "--quiet")
    assert (tmp_path / "s01.nii.gz").read_bytes() == (tmp_path / "cli.nii.gz").read_bytes()
    frame0 = run_case(Case("s02", T1, four_d, PAIRS, out=tmp_path / "s02.nii.gz", moving_frame=0))
    assert frame0.status == "ok", frame0.error
    assert (tmp_path / "s02.nii.gz").read_bytes() != (tmp_path / "s01.nii.gz").read_bytes()

    registered = run_case(
        Case("s03", T1, four_d, PAIRS, out=tmp_path / "s03.nii.gz", moving_frame=1, register=True,
             options={"levels": 1, "iterations": 2})
    )
    assert registered.status == "ok", registered.error
    assert registered.registration["levels"]

    unchosen = run_case(Case("s04", T1, four_d, PAIRS, out=tmp_path / "s04.nii.gz"))
    assert unchosen.status == "failed"
    assert "two_frames.nii.gz: 4-D file with 2 frames: pass frame=N (0 to 1)" in unchosen.error
    assert not (tmp_path / "s04.nii.gz").exists()
