"""Shared fixtures: the repository's data and the `warpbench` binary that the package is compared against."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
DATA = REPO / "tests" / "data"
# The CLI twin of every function: `cargo build -p warpbench-app` (or the README's test command) builds it.
BIN = Path(os.environ.get("WARPBENCH_BIN", REPO / "target" / "debug" / "warpbench"))

# A small pair with 8 hand-made BigWarp pairs (tests/data/itk/README.md): fixed 16×14×12 at 2 mm, moving 16³ at
# 2.5 mm.
FIXED = DATA / "itk" / "field_input_fixed.nii.gz"
MOVING = DATA / "itk" / "field_input_moving.nii.gz"
PAIRS = DATA / "itk" / "field_pairs.csv"
# A real head MRI template (tests/data/PROVENANCE.md), 91×109×91 at 2 mm.
T1 = DATA / "nifti" / "avg152T1_LR_nifti.nii"


def run_cli(*args: object, expect: int = 0) -> subprocess.CompletedProcess:
    """Runs the `warpbench` binary; fails the test unless it exits with `expect`."""
    if not BIN.exists():
        pytest.fail(f"{BIN} is missing: build it with `cargo build -p warpbench-app` or set WARPBENCH_BIN")
    done = subprocess.run([str(BIN), *map(str, args)], capture_output=True, text=True)
    assert done.returncode == expect, f"exit {done.returncode}: {done.stderr}"
    return done


def cli_json(*args: object) -> dict:
    return json.loads(run_cli(*args, "--json", "--quiet").stdout)


def session_json(fixed: object, moving: object, **extra: object) -> str:
    """A window session as the window saves one (schema warpbench-session/1) of `fixed` and `moving`, no landmarks and
    the window's usual settings, with `extra` keys set (`landmarks`, `field`, ...)."""
    return json.dumps({
        "schema": "warpbench-session/1", "fixed": str(fixed), "moving": str(moving), "landmarks": [],
        "settings": {"blend": "red-cyan", "mix_weight": 0.5, "checker_mm": 16.0, "shading": "iso",
                     "samples_per_voxel": 1.0, "method": "tps", "stiffness": 0.0, "bspline_levels": 4,
                     "control_texels": 64, "show_landmarks": True},
        "layers": [{"preset": "mr-t1", "window_low": 0.0, "window_high": 100.0, "visible": True},
                   {"preset": "mr-t1", "window_low": 0.0, "window_high": 100.0, "visible": True}],
        "camera": {"azimuth_deg": 30.0, "elevation_deg": 10.0, "zoom": 100.0, "target_lps": [0.0, 0.0, 0.0]},
        "slice_mm": [0.0, 0.0, 0.0], "clean_exit": True, **extra,
    })


@pytest.fixture
def cli():
    return run_cli
