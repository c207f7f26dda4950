"""Volumes: the readers against independent ones (nibabel, SimpleITK), zero-copy arrays, and conversions."""

from __future__ import annotations

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA, FIXED, T1

nib = pytest.importorskip("nibabel")
sitk = pytest.importorskip("SimpleITK")


def test_read_volume_matches_nibabel_samples_and_placement():
    v = wb.read_volume(T1)
    img = nib.load(str(T1))
    np.testing.assert_array_equal(v.array, np.asanyarray(img.dataobj))
    # nibabel's affine is RAS; ours is LPS.
    np.testing.assert_allclose(v.lps_from_index, np.diag([-1, -1, 1, 1]) @ img.affine, atol=1e-6)
    np.testing.assert_allclose(v.spacing, img.header.get_zooms()[:3])
    assert v.shape == img.shape


def test_the_array_is_the_readers_buffer_in_i_j_k_order():
    v = wb.read_volume(FIXED)
    assert v.array.flags["F_CONTIGUOUS"]
    # numpy does not own the samples: they are the Rust reader's vector, handed over without a copy.
    assert not v.array.flags["OWNDATA"]
    assert v.array.base is not None


def test_to_sitk_and_back_keeps_samples_and_geometry():
    v = wb.read_volume(T1)
    image = v.to_sitk()
    np.testing.assert_array_equal(sitk.GetArrayViewFromImage(image).T, v.array)
    # SimpleITK's own index-to-physical map agrees with lps_from_index at a corner voxel.
    ijk = (90, 0, 45)
    expected = v.lps_from_index @ np.array([*ijk, 1.0])
    np.testing.assert_allclose(image.TransformIndexToPhysicalPoint(ijk), expected[:3], atol=1e-9)
    back = wb.Volume.from_sitk(image)
    np.testing.assert_array_equal(back.array, v.array)
    np.testing.assert_allclose(back.lps_from_index, v.lps_from_index, atol=1e-12)


def test_to_nibabel_round_trip():
    v = wb.read_volume(FIXED)
    img = v.to_nibabel()
    back = wb.Volume.from_nibabel(img)
    np.testing.assert_array_equal(back.array, v.array)
    np.testing.assert_allclose(back.lps_from_index, v.lps_from_index)


def test_from_array_converts_types_as_the_readers_do():
    m = np.diag([1.0, 2.0, 3.0, 1.0])
    assert wb.Volume.from_array(np.zeros((2, 3, 4), np.int8), m).array.dtype == np.int16
    assert wb.Volume.from_array(np.zeros((2, 3, 4), np.float64), m).array.dtype == np.float32
    assert wb.Volume.from_array(np.zeros((2, 3, 4), bool), m).array.dtype == np.uint8
    kept = np.zeros((2, 3, 4), np.int16)
    assert wb.Volume.from_array(kept, m).array is kept
    with pytest.raises(ValueError, match="3-D"):
        wb.Volume.from_array(np.zeros((2, 3)), m)
    with pytest.raises(ValueError, match="4×4"):
        wb.Volume.from_array(kept, np.eye(3))


def test_written_volume_reads_back_in_nibabel(tmp_path):
    rng = np.random.default_rng(1)
    a = np.asfortranarray(rng.integers(-1000, 1000, size=(5, 6, 7)).astype(np.int16))
    m = np.array([[0.0, 0.0, 1.5, 10.0], [-2.0, 0.0, 0.0, 20.0], [0.0, 1.25, 0.0, -5.0], [0, 0, 0, 1]])
    wb.Volume.from_array(a, m).write(tmp_path / "v.nii.gz")
    img = nib.load(str(tmp_path / "v.nii.gz"))
    np.testing.assert_array_equal(np.asanyarray(img.dataobj), a)
    np.testing.assert_allclose(np.diag([-1, -1, 1, 1]) @ img.affine, m, atol=1e-4)
    back = wb.read_volume(tmp_path / "v.nii.gz")
    np.testing.assert_array_equal(back.array, a)


def test_bad_files_raise_with_the_file_named(tmp_path):
    with pytest.raises(OSError) as e:
        wb.read_volume(tmp_path / "missing.nii")
    assert "missing.nii" in str(e.value)
    with pytest.raises(ValueError) as e:
        wb.read_volume(DATA / "nifti" / "not-nifti.nii")
    assert "not-nifti.nii" in str(e.value)
    with pytest.raises(ValueError, match="v.xyz"):
        wb.Volume.from_array(np.zeros((2, 2, 2), np.uint8), np.eye(4)).write(tmp_path / "v.xyz")
    assert not (tmp_path / "v.xyz").exists()


def test_a_dicom_folder_of_several_series_reads_the_series_chosen():
    folder = DATA / "dicom" / "mixed_ct5n_mr_small"
    with pytest.raises(ValueError, match=r"holds 2 DICOM series[\s\S]*pass series=UID to read one"):
        wb.read_volume(folder)
    read = 0
    for uid in sitk.ImageSeriesReader.GetGDCMSeriesIDs(str(folder)):
        files = sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(folder), uid)
        v = wb.read_volume(folder, series=uid)
        assert v.header["metadata"]["series_instance_uid"] == uid
        if len(files) < 2:
            continue  # SimpleITK reads a one-file series as a 2-D image
        image = sitk.ReadImage(files)
        np.testing.assert_allclose(v.array, sitk.GetArrayViewFromImage(image).T)
        ijk = (1, 2, len(files) - 1)
        expected = v.lps_from_index @ np.array([*ijk, 1.0])
        np.testing.assert_allclose(image.TransformIndexToPhysicalPoint(ijk), expected[:3], atol=1e-4)
        read += 1
    assert read == 1, "the CT series of five files was compared"
    with pytest.raises(ValueError, match="mixed_ct5n_mr_small"):
        wb.read_volume(folder, series="1.2.3")
    with pytest.raises(ValueError, match="not both"):
        wb.read_volume(folder, frame=0, series="1.2.3")
    with pytest.raises(ValueError, match="a DICOM series was chosen, but this is not DICOM"):
        wb.read_volume(T1, series="1.2.3")
