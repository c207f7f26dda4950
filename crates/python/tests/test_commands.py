"""align, register and suggest against the CLI's --json on the same inputs, and the error contract."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import warpbench as wb
from conftest import PAIRS, T1, cli_json, session_json


def without_times(value):
    """A report less its wall times (the only fields two runs may differ in)."""
    if isinstance(value, dict):
        return {k: without_times(v) for k, v in value.items() if not (k.endswith("_s") or k == "seconds")}
    if isinstance(value, list):
        return [without_times(v) for v in value]
    return value


@pytest.fixture(scope="module")
def shifted(tmp_path_factory):
    """The head MRI moved by (4, -3, 2) mm and turned 3° about S: a pair with a known rigid answer."""
    head = wb.read_volume(T1)
    a = np.deg2rad(3.0)
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    turn[:3, 3] = [4.0, -3.0, 2.0]
    path = tmp_path_factory.mktemp("pair") / "moved.nii.gz"
    wb.Volume.from_array(head.array, turn @ head.lps_from_index).write(path)
    return path, turn


def test_align_returns_the_clis_report(tmp_path, shifted):
    moved, turn = shifted
    options = dict(samples=4000, shrink=[4, 2], seed=3)
    py = wb.align(T1, moved, out_tfm=tmp_path / "py.tfm", **options)
    cli = cli_json("align", "--fixed", T1, "--moving", moved, "--out-tfm", tmp_path / "cli.tfm", "--samples", 4000,
                   "--shrink", "4,2", "--seed", 3)
    py["moving_from_fixed"] = py["moving_from_fixed"].tolist()
    assert without_times(py) | {"out": ""} == without_times(cli) | {"out": ""}
    assert (tmp_path / "py.tfm").read_bytes() == (tmp_path / "cli.tfm").read_bytes()
    # The answer: a fixed point x is at turn·x in the moved copy.
    np.testing.assert_allclose(np.array(cli["moving_from_fixed"])[:3, 3], turn[:3, 3], atol=1.5)


def test_register_returns_the_clis_report_and_field(tmp_path, shifted):
    moved, _ = shifted
    flags = dict(levels=1, iterations=4, samples=4000, grid_mm=32, method="affine")
    pairs = wb.read_landmarks(PAIRS)
    # The pairs of the known map: q on the head, p = turn·q on the moved copy.
    _, turn = shifted
    q = pairs.fixed
    p = (turn @ np.c_[q, np.ones(len(q))].T).T[:, :3]
    known = wb.Pairs(p, q, names=pairs.names)
    wb.write_landmarks(tmp_path / "known.csv", known)
    py = wb.register(T1, moved, tmp_path / "known.csv", out_field=tmp_path / "py.nii.gz", **flags)
    cli = cli_json("register", "--fixed", T1, "--moving", moved, "--landmarks", tmp_path / "known.csv",
                   "--out-field", tmp_path / "cli.nii.gz", "--levels", 1, "--iterations", 4, "--samples", 4000,
                   "--grid-mm", 32, "--method", "affine")
    assert without_times(py) | {"out_field": ""} == without_times(cli) | {"out_field": ""}
    assert (tmp_path / "py.nii.gz").read_bytes() == (tmp_path / "cli.nii.gz").read_bytes()
    # Pairs given as an object go through a file of the same pairs: the same result.
    again = wb.register(T1, moved, known, out_field=tmp_path / "again.nii.gz", **flags)
    assert (tmp_path / "again.nii.gz").read_bytes() == (tmp_path / "py.nii.gz").read_bytes()
    assert again["jacobian"]["min_det"] > 0


def test_register_reads_a_sessions_volumes_and_pairs(tmp_path, shifted):
    moved, turn = shifted
    # The session's method (a TPS) stands: --session excludes --method.
    flags = dict(levels=1, iterations=4, samples=4000, grid_mm=32)
    q = wb.read_landmarks(PAIRS).fixed
    p = (turn @ np.c_[q, np.ones(len(q))].T).T[:, :3]
    landmarks = [{"name": f"P{i}", "active": True, "moving_lps": list(a), "fixed_lps": list(b)}
                 for i, (a, b) in enumerate(zip(p.tolist(), q.tolist()))]
    session = tmp_path / "case.warpbench.json"
    session.write_text(session_json(T1, moved, landmarks=landmarks))
    # The session alone: its volumes and its pairs, as the same call with the volumes given.
    alone = wb.register(session=session, out_field=tmp_path / "alone.nii.gz", **flags)
    given = wb.register(T1, moved, session=session, out_field=tmp_path / "given.nii.gz", **flags)
    assert (tmp_path / "alone.nii.gz").read_bytes() == (tmp_path / "given.nii.gz").read_bytes()
    assert alone["pairs"] == given["pairs"] == len(landmarks)
    with pytest.raises(ValueError, match="give fixed and moving, or session="):
        wb.register(out_field=tmp_path / "none.nii.gz", **flags)
    assert not (tmp_path / "none.nii.gz").exists()


def test_register_matches_by_the_metric_asked_for(tmp_path, shifted):
    moved, _ = shifted
    flags = dict(levels=1, iterations=4, samples=4000, grid_mm=32, method="affine")
    report = wb.register(T1, moved, out_field=tmp_path / "lncc.nii.gz", metric="lncc", **flags)
    assert report["settings"]["metric"] == "lncc"
    level = report["levels"][0]
    # Local correlation is a mean of squared correlations, and the registration raises it.
    assert 0.0 <= level["similarity_start"] < level["similarity"] <= 1.0
    with pytest.raises(ValueError, match="lncc"):
        wb.register(T1, moved, out_field=tmp_path / "x.nii.gz", metric="xcorr", **flags)
    assert not (tmp_path / "x.nii.gz").exists()


def test_errors_are_python_exceptions_with_the_clis_message(tmp_path):
    # A file the system refuses is an OSError (here FileNotFoundError) naming it.
    with pytest.raises(FileNotFoundError) as e:
        wb.register(T1, T1, tmp_path / "nope.csv", out_field=tmp_path / "f.nii.gz")
    assert "nope.csv" in str(e.value)
    with pytest.raises(OSError) as e:
        wb.align(T1, tmp_path / "missing.nii", out_tfm=tmp_path / "a.tfm")
    assert "missing.nii" in str(e.value)
    assert not (tmp_path / "a.tfm").exists()
    # Bad content and bad usage are ValueErrors.
    (tmp_path / "bad.csv").write_text('"Pt-0","true","1","2"\n')
    with pytest.raises(ValueError) as e:
        wb.register(T1, T1, tmp_path / "bad.csv", out_field=tmp_path / "f.nii.gz")
    assert "bad.csv" in str(e.value)
    with pytest.raises(ValueError, match="unexpected argument"):
        wb.align(T1, T1, no_such_flag=3)
    assert not (tmp_path / "f.nii.gz").exists()


def test_a_panic_is_a_runtime_error_and_the_interpreter_goes_on():
    code = (
        "import warpbench._warpbench as n\n"
        "try:\n"
        "    n.panic_for_test()\n"
        "except RuntimeError as e:\n"
        "    print('caught:', e)\n"
        "print('still here')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "caught: internal error in warpbench" in done.stdout
    assert "still here" in done.stdout


def test_the_gil_is_released_during_long_work():
    """A Python thread ticks while a long Rust call runs. Were the GIL held, it could not tick at all during the
    call; the call is repeated (up to 5 times) so that a busy machine that never schedules the thread in one call
    does not fail the test."""
    import threading

    head = wb.read_volume(T1)
    warp = wb.fit(wb.read_landmarks(PAIRS), fixed=head, moving=head)
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(1)
            stop.wait(0.001)

    t = threading.Thread(target=tick)
    t.start()
    try:
        during = []
        for _ in range(5):
            before = len(ticks)
            warp.field(head)  # ~0.9 M exact TPS evaluations in Rust
            during.append(len(ticks) - before)
            if during[-1] > 0:
                break
    finally:
        stop.set()
        t.join()
    assert max(during) > 0, during


def test_read_volume_places_the_volume_where_info_does():
    info = cli_json("info", T1)
    v = wb.read_volume(T1)
    assert list(v.shape) == info["dims"]
    np.testing.assert_array_equal(v.lps_from_index, np.array(info["lps_from_index"]))
    np.testing.assert_array_equal(v.spacing, info["spacing_mm"])


def test_suggest_returns_the_clis_report(tmp_path, shifted):
    moved, turn = shifted
    pairs = wb.read_landmarks(PAIRS)
    q = pairs.fixed
    p = (turn @ np.c_[q, np.ones(len(q))].T).T[:, :3]
    wb.write_landmarks(tmp_path / "known.csv", wb.Pairs(p, q, names=pairs.names))
    points = p[:2] + [1.0, 0.0, -1.0]
    with open(tmp_path / "points.csv", "w") as f:
        f.write("x,y,z\n" + "".join(f"{float(a)!r},{float(b)!r},{float(c)!r}\n" for a, b, c in points))
    cli = cli_json("suggest", "--fixed", T1, "--moving", moved, "--landmarks", tmp_path / "known.csv", "--points",
                   tmp_path / "points.csv", "--out", tmp_path / "cli.csv")
    py = wb.suggest(T1, moved, points, tmp_path / "known.csv", out=tmp_path / "py.csv")
    assert without_times(py) | {"out": "", "points": ""} == without_times(cli) | {"out": "", "points": ""}
    assert (tmp_path / "py.csv").read_bytes() == (tmp_path / "cli.csv").read_bytes()
