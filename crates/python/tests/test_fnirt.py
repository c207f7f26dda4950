"""FSL FNIRT warps (``fnirt --cout`` coefficients, ``--fout`` and ``convertwarp`` deformation fields), read from Python
against their reference and input volumes, as fslpy 3.29.1 (FSL's own Python library) reads them.

The fixtures and ``reference.json`` come from ``data-scripts/fnirt_fixtures.py`` (``tests/data/fnirt/``): for each
warp, where fslpy's ``readFnirt(...).transform`` takes 60 reference voxels, in LPS mm. ``read_field`` with
``fixed=`` the reference and ``moving=`` the input gives the pull-back on the reference grid, ``source`` ``"fnirt"``,
that takes each of them there; a deformation field says how it was read; without the volumes it raises.

What warpbench writes as FNIRT's field (``Warp.field(format="fnirt")``, ``warpbench field --format fnirt``) is read
by fslpy itself (``fsl.transform.fnirt.readFnirt``, which tells relative from absolute on its own) to the same
points, and nibabel sees FNIRT's header (intent 2006, float32, (X, Y, Z, 3), the reference's sform).

Needs numpy, nibabel, fslpy (``.ci/run`` installs 3.29.1) and the CLI binary (``conftest.py``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA, run_cli

nib = pytest.importorskip("nibabel")
fsl_fnirt = pytest.importorskip("fsl.transform.fnirt")
fsl_image = pytest.importorskip("fsl.data.image")

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


def fslpy_points(path, reference: str) -> np.ndarray:
    """Where fslpy's own reading of the FNIRT file at ``path`` takes the fixture's voxels, LPS mm."""
    warp = fsl_fnirt.readFnirt(str(path), fsl_image.Image(str(FNIRT / "src.nii.gz")), fsl_image.Image(str(FNIRT / reference)))
    world = warp.transform(np.array(REFERENCE["voxels"], dtype=float), from_="voxel", to="world")
    return world * np.array([-1.0, -1.0, 1.0])


@pytest.mark.parametrize("coef,reference", [("coef_neuro.nii.gz", "ref_neuro.nii.gz"), ("coef_radio.nii.gz", "ref_radio.nii.gz")])
def test_what_warpbench_writes_as_fnirt_fslpy_reads_as_the_same_warp(tmp_path, coef: str, reference: str) -> None:
    want = np.array(REFERENCE["warps"][coef]["moving_lps"])
    fixed = wb.read_volume(FNIRT / reference)
    moving = wb.read_volume(FNIRT / "src.nii.gz")
    warp = wb.fit(wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3))), fixed=fixed, moving=moving, initial_field=FNIRT / coef)
    written = tmp_path / "from_python.nii.gz"
    warp.field(path=written, format="fnirt")
    cli = tmp_path / "from_cli.nii.gz"
    run_cli("field", "--fixed", FNIRT / reference, "--moving", FNIRT / "src.nii.gz", "--field", FNIRT / coef,
            "--format", "fnirt", "--out", cli, "--quiet")
    for path in (written, cli):
        img = nib.load(path)
        assert (int(img.header["intent_code"]), img.shape, img.get_data_dtype()) == (2006, fixed.shape + (3,), np.float32)
        np.testing.assert_allclose(img.affine, nib.load(FNIRT / reference).affine, atol=1e-5)
        # fslpy decides relative or absolute by itself, and maps the voxels where it maps them through the original.
        warp_read = fsl_fnirt.readFnirt(str(path), fsl_image.Image(str(FNIRT / "src.nii.gz")), fsl_image.Image(str(FNIRT / reference)))
        assert warp_read.deformationType == "relative"
        np.testing.assert_allclose(fslpy_points(path, reference), want, atol=1e-4)


def test_fnirt_output_needs_the_moving_volume_a_nifti_name_and_the_pullback(tmp_path) -> None:
    fixed = wb.read_volume(FNIRT / "ref_neuro.nii.gz")
    moving = wb.read_volume(FNIRT / "src.nii.gz")
    pairs = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(pairs, fixed=fixed, moving=moving, initial_field=FNIRT / "coef_neuro.nii.gz")
    with pytest.raises(ValueError, match=r"w\.nrrd.*NIfTI"):
        warp.field(path=tmp_path / "w.nrrd", format="fnirt")
    with pytest.raises(ValueError, match=r"w\.nii\.gz.*pull-back"):
        warp.field(fixed, path=tmp_path / "w.nii.gz", format="fnirt", direction="forward")
    assert not any(tmp_path.iterdir())
