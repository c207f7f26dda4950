"""FSL FNIRT warps (``fnirt --cout`` coefficients, ``--fout`` and ``convertwarp`` deformation fields), read from Python
against their reference and input volumes, as fslpy 3.29.1 (FSL's own Python library) reads them.

The fixtures and ``reference.json`` come from ``data-scripts/fnirt_fixtures.py`` (``tests/data/fnirt/``): for each
warp, where fslpy's ``readFnirt(...).transform`` takes 60 reference voxels, in LPS mm. ``read_field`` with
``fixed=`` the reference and ``moving=`` the input gives the pull-back on the reference grid, ``source`` ``"fnirt"``,
that takes each of them there; a deformation field says how it was read; without the volumes it raises.

Needs the CLI binary only for ``conftest.py``'s checks; numpy.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA

FNIRT = DATA / "fnirt"
REFERENCE = json.loads((FNIRT / "reference.json").read_text())


@pytest.mark.parametrize("name", sorted(REFERENCE["warps"]))
def test_a_warp_takes_the_reference_voxels_where_fslpy_takes_them(name: str) -> None:
    case = REFERENCE["warps"][name]
    fixed = wb.read_volume(FNIRT / f"{case['reference']}.nii.gz")
    moving = wb.read_volume(FNIRT / "src.nii.gz")
    field = wb.read_field(FNIRT / name, fixed=fixed, moving=moving)
    assert (field.source, field.direction, field.shape) == ("fnirt", "pullback", fixed.shape)
    np.testing.assert_allclose(field.lps_from_index, fixed.lps_from_index)
    if "detected" in case:
        assert any(w.startswith(f"read as {case['detected']}") for w in field.warnings), field.warnings
    voxels = np.array(REFERENCE["voxels"])
    homogeneous = np.c_[voxels, np.ones(len(voxels))]
    x = homogeneous @ np.asarray(fixed.lps_from_index).T
    got = x[:, :3] + field.array[voxels[:, 0], voxels[:, 1], voxels[:, 2]]
    np.testing.assert_allclose(got, np.array(case["moving_lps"]), atol=1e-4)


def test_without_its_volumes_or_against_another_reference_it_raises_naming_the_file() -> None:
    with pytest.raises(ValueError, match=r"coef_neuro\.nii\.gz.*FNIRT"):
        wb.read_field(FNIRT / "coef_neuro.nii.gz")
    src = wb.read_volume(FNIRT / "src.nii.gz")
    with pytest.raises(ValueError, match=r"coef_neuro\.nii\.gz.*fnirt's --ref"):
        wb.read_field(FNIRT / "coef_neuro.nii.gz", fixed=src, moving=src)
    with pytest.raises(ValueError, match=r"topup_field\.nii\.gz.*TOPUP"):
        wb.read_field(FNIRT / "topup_field.nii.gz", fixed=src, moving=src)
