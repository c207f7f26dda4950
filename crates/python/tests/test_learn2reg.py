"""Learn2Reg's displacement fields (`.npz`, and the NIfTI form since 2022), through the CLI, against NumPy, nibabel
and SimpleITK.

Learn2Reg's evaluation (github.com/MDL-UzL/L2R, `evaluation/L2RTest/utils.py`; `evaluation/evaluation.py` since 2022
with `nib.load(disp_path).get_fdata()`) loads an array of shape (X, Y, Z, 3) and maps a fixed voxel index i to the
moving voxel index i + d[i]. Here the fixed volume (16×14×12 at 2 mm) and the moving one (16³ at 2.5 mm) have
different grids, so a step in voxels is not one in mm:

- `warpbench field --out disp.npz` writes what NumPy loads as float16 `arr_0`, and `--format learn2reg --out
  disp.nii.gz` what nibabel loads as a float32 (X, Y, Z, 3) array with the fixed image's affine; each step is
  SimpleITK's moving continuous index of x + D(x), with D the ITK field `warpbench field` writes, minus the fixed
  index;
- `warpbench warp --field` of a field NumPy or nibabel wrote resamples as SimpleITK does through the same steps
  turned into mm by SimpleITK's geometry (the NIfTI form only with `--field-format learn2reg`);
- Python's `read_field` given the two volumes reads the steps to SimpleITK's mm field;
- the readers that are not given the pair refuse an `.npz`, and every reader a NIfTI form it is not told of, naming
  the file and how to read it.
"""

from __future__ import annotations

import numpy as np
import pytest

import warpbench as wb
from conftest import FIXED, MOVING, cli_json, run_cli

sitk = pytest.importorskip("SimpleITK")
nib = pytest.importorskip("nibabel")


def indices(shape):
    return np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), axis=-1).reshape(-1, 3)


def pairs(tmp_path):
    """Six BigWarp pairs (moving, then fixed, LPS mm) inside both boxes, moved by up to 3 mm."""
    rows = [
        ((-6, -5, -4), (-8, -6, -3)),
        ((7, -4, 2), (6, -6, 4)),
        ((-5, 8, 3), (-4, 6, 1)),
        ((6, 6, -5), (8, 7, -3)),
        ((0, 0, 6), (1, -2, 7)),
        ((2, -1, -7), (0, 0, -8)),
    ]
    path = tmp_path / "pairs.csv"
    path.write_text("".join(f'"Pt-{n}","true",{",".join(f"{v:.1f}" for v in (*m, *f))}\n' for n, (m, f) in enumerate(rows)))
    return path


def test_field_writes_the_steps_simpleitk_computes_from_the_itk_field(tmp_path):
    npz, nii = tmp_path / "disp_0001_0002.npz", tmp_path / "disp.nii.gz"
    landmarks = pairs(tmp_path)
    summary = cli_json("field", "--fixed", FIXED, "--moving", MOVING, "--landmarks", landmarks, "--out", npz)
    assert summary["format"] == "learn2reg" and summary["grid"] == "fixed"
    run_cli("field", "--fixed", FIXED, "--moving", MOVING, "--landmarks", landmarks, "--out", nii, "--quiet")
    with np.load(npz) as archive:
        assert archive.files == ["arr_0"]
        steps = archive["arr_0"]
    fixed, moving = sitk.ReadImage(str(FIXED)), sitk.ReadImage(str(MOVING))
    assert steps.dtype == np.float16 and steps.shape == (*fixed.GetSize(), 3)
    field = sitk.GetArrayFromImage(sitk.ReadImage(str(nii))).transpose(2, 1, 0, 3)  # k-j-i-c to i-j-k-c
    want = np.empty(steps.shape)
    for i, j, k in indices(steps.shape[:3]):
        x = np.array(fixed.TransformIndexToPhysicalPoint((int(i), int(j), int(k))))
        u = x + field[i, j, k].astype(np.float64)
        want[i, j, k] = np.array(moving.TransformPhysicalPointToContinuousIndex(tuple(u))) - (i, j, k)
    # float16 holds a step within 2^-11 of its size; the f32 vectors of the ITK field add ~1e-6 voxels.
    np.testing.assert_allclose(steps.astype(np.float64), want, rtol=2.0**-11, atol=1e-4)
    assert np.abs(want).max() > 1.0, "the steps must be more than the grid change"

    # The NIfTI form since 2022: what nibabel loads, float32 (X, Y, Z, 3) with the fixed image's affine.
    form = tmp_path / "disp_0001_0002.nii.gz"
    args = ("field", "--fixed", FIXED, "--moving", MOVING, "--landmarks", landmarks, "--format", "learn2reg")
    summary = cli_json(*args, "--out", form)
    assert summary["format"] == "learn2reg"
    image = nib.load(form)
    assert image.header["dim"][0] == 4 and image.header["intent_code"] == 0 and image.get_data_dtype() == np.float32
    np.testing.assert_allclose(image.affine, nib.load(FIXED).affine, rtol=0, atol=1e-5)
    np.testing.assert_allclose(image.get_fdata(), want, rtol=0, atol=1e-4)
    done = run_cli(*args, "--out", tmp_path / "disp.nrrd", expect=2)
    assert "disp.nrrd" in done.stderr and ".nii.gz" in done.stderr


def test_warp_reads_a_numpy_field_as_simpleitk_resamples_through_it(tmp_path):
    fixed, moving = sitk.ReadImage(str(FIXED), sitk.sitkFloat64), sitk.ReadImage(str(MOVING), sitk.sitkFloat64)
    shape = fixed.GetSize()
    ijk = indices(shape).reshape(*shape, 3).astype(np.float64)
    # A smooth step of up to 1.5 moving voxels, exact in float16 after rounding here.
    steps = np.stack(
        [1.5 * np.sin(ijk[..., 1] / 4.0), 0.75 * np.cos(ijk[..., 2] / 5.0), 0.5 - ijk[..., 0] / 16.0], axis=-1
    ).astype(np.float16)
    npz = tmp_path / "disp.npz"
    np.savez_compressed(npz, steps)
    # The same steps as an ITK displacement field in mm, by SimpleITK's geometry of the two images.
    mm = np.empty((*shape, 3))
    for i, j, k in indices(shape):
        x = np.array(fixed.TransformIndexToPhysicalPoint((int(i), int(j), int(k))))
        to = tuple(float(v) for v in (i, j, k) + steps[i, j, k].astype(np.float64))
        mm[i, j, k] = np.array(moving.TransformContinuousIndexToPhysicalPoint(to)) - x
    # Python reads the steps against the two volumes to the same field, in LPS mm (SimpleITK's physical space).
    read = wb.read_field(npz, fixed=wb.read_volume(FIXED), moving=wb.read_volume(MOVING))
    assert (read.source, read.direction, read.array.shape) == ("learn2reg", "pullback", (*shape, 3))
    np.testing.assert_allclose(read.array, mm, rtol=0, atol=1e-5)
    image = sitk.GetImageFromArray(mm.transpose(2, 1, 0, 3), isVector=True)
    image.CopyInformation(fixed)
    transform = sitk.DisplacementFieldTransform(image)
    want = sitk.GetArrayFromImage(sitk.Resample(moving, fixed, transform, sitk.sitkLinear, 0.0)).transpose(2, 1, 0)

    # The same steps in the NIfTI form, as the challenge's zero fields are saved (float32, the identity affine).
    form = tmp_path / "disp_0001_0002.nii.gz"
    nib.save(nib.Nifti1Image(steps.astype(np.float32), np.eye(4)), form)
    read = wb.read_field(form, fixed=wb.read_volume(FIXED), moving=wb.read_volume(MOVING), learn2reg=True)
    assert read.source == "learn2reg"
    np.testing.assert_allclose(read.array, mm, rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match=r"disp_0001_0002\.nii\.gz.*Learn2Reg.*learn2reg=True"):
        wb.read_field(form)

    scale = np.abs(want).max()
    assert scale > 0
    for field, extra in ((npz, ()), (form, ("--field-format", "learn2reg"))):
        out = tmp_path / "warped.nii.gz"
        run_cli("warp", "--fixed", FIXED, "--moving", MOVING, "--field", field, *extra, "--exact", "--float",
                "--out", out, "--quiet", "--force")
        got = sitk.GetArrayFromImage(sitk.ReadImage(str(out))).transpose(2, 1, 0)
        # At each fixed voxel centre both read the moving volume at the same point, trilinearly: f32 arithmetic apart.
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * scale)
    assert np.abs(steps).max() > 1.0
    done = run_cli("warp", "--fixed", FIXED, "--moving", MOVING, "--field", form, "--out", tmp_path / "w.nii.gz",
                   expect=2)
    assert "disp_0001_0002.nii.gz" in done.stderr and "--field-format learn2reg" in done.stderr

    # Under the landmarks, with no pairs: the form as a Field (Python) and with --initial-field-format (CLI) maps
    # fixed points as SimpleITK's transform of the same field in mm, inside the fixed box and outside it.
    box = np.array(shape) - 1
    centres = np.array([[2.5, 3.0, 1.5], [0.2, 7.7, 9.1], box * 0.5, box * [0.9, 0.1, 0.6], [-20.0, 3.0, 4.0]])
    points = np.array([fixed.TransformContinuousIndexToPhysicalPoint(tuple(c)) for c in centres])
    want = np.array([transform.TransformPoint(tuple(p)) for p in points])
    assert np.abs(want[:4] - points[:4]).max() > 1.0 and np.allclose(want[4], points[4])
    none = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(none, initial_field=read)
    np.testing.assert_allclose(warp.pullback(points), want, rtol=0, atol=1e-5)
    targets, mapped, empty = tmp_path / "targets.csv", tmp_path / "mapped.csv", tmp_path / "none.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points.tolist()))
    empty.write_text("")
    run_cli("points", "--fixed", FIXED, "--moving", MOVING, "--initial-field", form, "--initial-field-format",
            "learn2reg", "--landmarks", empty, "--from", "fixed", "--in", targets, "--out", mapped, "--quiet")
    got = np.array([[float(v) for v in line.split(",")[:3]] for line in mapped.read_text().splitlines()])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)


def test_readers_without_the_pair_refuse_an_npz_and_a_wrong_shape_by_name(tmp_path):
    npz = tmp_path / "disp.npz"
    np.savez_compressed(npz, np.zeros((16, 14, 12, 3), np.float16))
    with pytest.raises(ValueError, match=r"disp\.npz: a Learn2Reg field .* read_field\(path, fixed=\.\.\., moving=\.\.\.\)"):
        wb.read_field(npz)
    with pytest.raises(ValueError, match=r"disp\.npz: give both fixed and moving"):
        wb.read_field(npz, fixed=wb.read_volume(FIXED))
    wrong = tmp_path / "wrong.npz"
    np.savez_compressed(wrong, np.zeros((16, 14, 11, 3), np.float16))
    for command, out in (("warp", "w.nii.gz"), ("render", "r.png")):
        done = run_cli(command, "--fixed", FIXED, "--moving", MOVING, "--field", wrong, "--out", tmp_path / out,
                       expect=2)
        assert "wrong.npz" in done.stderr and "[16, 14, 11]" in done.stderr and "[16, 14, 12]" in done.stderr
        assert not (tmp_path / out).exists()


def test_python_writes_both_forms_as_the_cli_does(tmp_path):
    """`Warp.field(path=…, format="learn2reg")` (or a path ending .npz) writes the bytes `warpbench field` writes for
    the same pairs: the .npz byte for byte (it stamps no time), the NIfTI form to the same steps; without the moving
    volume, or for the forward direction, it raises ValueError naming the file."""
    landmarks = pairs(tmp_path)
    fixed, moving = wb.read_volume(FIXED), wb.read_volume(MOVING)
    warp = wb.fit(wb.read_landmarks(landmarks), "tps", fixed=fixed, moving=moving)
    for name, extra in (("disp.npz", ()), ("disp.nii.gz", ("--format", "learn2reg"))):
        ours, theirs = tmp_path / f"py_{name}", tmp_path / f"cli_{name}"
        warp.field(path=ours, format="learn2reg" if extra else "itk")
        run_cli("field", "--fixed", FIXED, "--moving", MOVING, "--landmarks", landmarks, *extra, "--out", theirs,
                "--quiet")
        if name.endswith(".npz"):
            assert ours.read_bytes() == theirs.read_bytes()
        else:
            np.testing.assert_allclose(nib.load(ours).get_fdata(), nib.load(theirs).get_fdata(), rtol=0, atol=1e-5)
            np.testing.assert_allclose(nib.load(ours).affine, nib.load(theirs).affine, rtol=0, atol=1e-6)
    alone = wb.fit(wb.read_landmarks(landmarks), "tps")
    with pytest.raises(ValueError, match=r"alone\.npz: Learn2Reg's field .* moving="):
        alone.field(fixed, path=tmp_path / "alone.npz")
    with pytest.raises(ValueError, match=r"fwd\.nii\.gz: Learn2Reg's field maps fixed voxels"):
        warp.field(moving, direction="forward", path=tmp_path / "fwd.nii.gz", format="learn2reg")
