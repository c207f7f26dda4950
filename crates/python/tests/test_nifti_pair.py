"""NIfTI pairs (``.hdr`` + ``.img``), as SPM and older tools write them, against nibabel.

``read_volume`` and the command line open a pair by either of its names to nibabel's values and affine (in LPS);
an Analyze 7.5 pair, whose orientation is not stored, is refused with a message naming the file.
Needs nibabel and numpy, and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")

import warpbench as wb  # noqa: E402
from conftest import DATA, run_cli  # noqa: E402

PAIRS = DATA / "nifti_pair"
FLIP = np.diag([-1.0, -1.0, 1.0, 1.0])


@pytest.mark.parametrize("name", ["oblique_i16.hdr", "oblique_i16.img", "big_endian_u16.img", "compressed_u8.hdr.gz"])
def test_a_pair_reads_as_nibabel_reads_it(name: str) -> None:
    theirs = nib.load(PAIRS / name)
    ours = wb.read_volume(PAIRS / name)
    np.testing.assert_allclose(ours.lps_from_index, FLIP @ theirs.affine, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.array, theirs.get_fdata(), rtol=1e-6, atol=1e-6)
    info = json.loads(run_cli("info", PAIRS / name, "--json", "--quiet").stdout)
    assert info["format"] == "nifti" and info["dims"] == list(theirs.shape)


def test_an_analyze_pair_is_refused() -> None:
    with pytest.raises(ValueError, match=r"analyze\.hdr: .*Analyze 7\.5 header, which stores no orientation"):
        wb.read_volume(PAIRS / "analyze.img")
    done = run_cli("info", PAIRS / "analyze.hdr", expect=2)
    assert "analyze.hdr" in done.stderr and "Analyze 7.5" in done.stderr
