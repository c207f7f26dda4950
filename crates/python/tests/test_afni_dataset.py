"""AFNI datasets (``.HEAD`` + ``.BRIK``) and AFNI's ``3dQwarp`` warps through Python, against nibabel and
nitransforms read here and now:

- AFNI's own datasets in nibabel's test data (the package's copies, not the repository's) read by ``read_volume`` to
  nibabel's affine and values, each sub-brick chosen with ``frame=``;
- the repository's 3dQwarp-style warp (``data-scripts/afni_fixtures.py``: a dataset, named by either file, and AFNI's
  NIfTI form of it) read by ``read_field`` as the pull-back nitransforms maps every voxel centre to;
- an AFNI dataset that is not a warp, and a NIfTI warp without AFNI's labels, refused with ``ValueError``;
- a warp written with ``format="afni"`` read back as itself, laid out as AFNI saves a warp, and mapped by
  nitransforms' AFNI reader where warpbench's pull-back maps each point.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")
nitnl = pytest.importorskip("nitransforms.nonlinear")

import warpbench as wb  # noqa: E402
from conftest import DATA  # noqa: E402

NIBABEL_DATA = Path(nib.__file__).parent / "tests" / "data"
LPS_FROM_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


@pytest.mark.parametrize("name", ["example4d+orig.HEAD", "example4d+orig.BRIK.gz", "scaled+tlrc.HEAD"])
def test_afnis_datasets_read_as_nibabel_reads_them(name: str) -> None:
    image = nib.load(NIBABEL_DATA / name)
    values = image.get_fdata()
    values = values if values.ndim == 4 else values[..., None]
    for t in range(values.shape[3]):
        volume = wb.read_volume(NIBABEL_DATA / name, frame=t if values.shape[3] > 1 else None)
        np.testing.assert_allclose(volume.lps_from_index, LPS_FROM_RAS @ image.affine, atol=1e-9)
        # A scale factor is applied in float64 and kept as float32.
        np.testing.assert_allclose(volume.array, values[..., t], rtol=1e-6, atol=0)
        assert volume.header["geometry_source"]["kind"] == "afni"


def test_several_sub_bricks_need_a_frame() -> None:
    with pytest.raises(ValueError, match="3 frames"):
        wb.read_volume(NIBABEL_DATA / "example4d+orig.HEAD")


# (The other warp, `warp_lps+orig`, has no IJK_TO_DICOM_REAL, which nibabel needs: `crates/io/tests/afni_dataset.rs`
# checks it against the points nitransforms mapped from a copy with it.)
@pytest.mark.parametrize("name", ["warp_rai+tlrc.HEAD", "warp_rai+tlrc.BRIK", "warp_rai_WARP.nii.gz"])
def test_a_3dqwarp_warp_maps_voxels_where_nitransforms_maps_them(tmp_path: Path, name: str) -> None:
    field = wb.read_field(DATA / "afni_made" / name)
    assert (field.source, field.direction) == ("afni", "pullback")
    # nitransforms reads AFNI's warp from its NIfTI form: the one in the repository, or one made here from the
    # dataset nibabel reads.
    if name.endswith(".nii.gz"):
        nifti = DATA / "afni_made" / name
    else:
        image = nib.load(DATA / "afni_made" / name)
        nifti = tmp_path / "warp.nii"
        deltas = np.asanyarray(image.dataobj)
        nib.Nifti1Image(deltas.reshape(*deltas.shape[:3], 1, 3), image.affine).to_filename(nifti)
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in field.shape), indexing="ij"), axis=-1).reshape(-1, 3)
    fixed_lps = ijk @ field.lps_from_index[:3, :3].T + field.lps_from_index[:3, 3]
    ras = fixed_lps * [-1.0, -1.0, 1.0]
    want = np.asarray(nitnl.DenseFieldTransform.from_filename(nifti, fmt="afni").map(ras)) * [-1.0, -1.0, 1.0]
    got = fixed_lps + field.array.reshape(-1, 3)
    assert np.abs(got - want).max() < 1e-4


def test_what_is_not_an_afni_warp_is_refused() -> None:
    with pytest.raises(ValueError, match="not a 3dQwarp warp"):
        wb.read_field(DATA / "afni" / "example4d+orig.HEAD")
    with pytest.raises(ValueError, match="no AFNI extension labels it"):
        wb.read_field(DATA / "afni_made" / "nitransforms_afni.nii.gz")


def test_a_warp_written_for_afni_is_read_by_nitransforms_as_warpbench_maps_points(tmp_path: Path) -> None:
    from conftest import PAIRS, T1

    head = wb.read_volume(T1)
    warp = wb.fit(wb.read_landmarks(PAIRS), "tps", fixed=head, moving=head)
    out = tmp_path / "anat_WARP.nii.gz"
    sampled = warp.field(path=out, format="afni")
    back = wb.read_field(out)
    assert (back.source, back.direction) == ("afni", "pullback")
    np.testing.assert_array_equal(back.array, sampled)
    # AFNI's layout as nibabel sees it: (X, Y, Z, 1, 3), no intent, AFNI's extension (code 4).
    image = nib.load(out)
    assert image.shape == (*head.shape, 1, 3) and int(image.header["intent_code"]) == 0
    assert [e.get_code() for e in image.header.extensions] == [4]
    # nitransforms' AFNI reader maps voxel centres where warpbench's pull-back maps them.
    rng = np.random.default_rng(7)
    ijk = np.stack([rng.integers(0, n, 200) for n in head.shape], axis=1)
    lps = ijk @ head.lps_from_index[:3, :3].T + head.lps_from_index[:3, 3]
    theirs = np.asarray(nitnl.DenseFieldTransform.from_filename(out, fmt="afni").map(lps * [-1.0, -1.0, 1.0]))
    np.testing.assert_allclose(theirs * [-1.0, -1.0, 1.0], warp.pullback(lps), rtol=0, atol=1e-4)


def test_afnis_own_names_read_the_dataset() -> None:
    dataset = DATA / "afni" / "example4d+orig"
    np.testing.assert_array_equal(
        wb.read_volume(f"{dataset}[1]").array, wb.read_volume(f"{dataset}.HEAD", frame=1).array
    )
    assert wb.read_field(DATA / "afni_made" / "warp_rai+tlrc").source == "afni"
    with pytest.raises(ValueError, match="a list, a range or a label is not"):
        wb.read_volume(f"{dataset}[0..2]")
