"""ITK's HDF5 transform files (`.h5`) from SimpleITK, read by the warpbench CLI.

- A composite of two affines that SimpleITK writes to `.h5`, an Euler3DTransform `.tfm` and a VersorRigid3DTransform
  `.h5` (what its rigid registrations write): `warpbench points --initial` (too few pairs to refine it, so it alone is
  the warp) maps points where SimpleITK's TransformPoint puts them.
- A composite of an affine and a displacement field on the fixed grid, as antsRegistration's `Composite.h5` holds
  them: `warpbench warp --field` resamples the moving volume as SimpleITK's Resample does through the same file.
- `warpbench transform --out x.h5` and `align --out-tfm x.h5` write ITK's HDF5 transform file: SimpleITK reads the
  same class and numbers as from the `.tfm` of the same run.
- A session with a displacement field under its landmarks, which no `.tfm` holds: `transform --session S --out
  x.h5` writes a DisplacementFieldTransform that SimpleITK applies as `warpbench points --session` maps points.
- A warp over SimpleITK's B-spline result (`--initial-field` a composite `.tfm`, `--initial` an affine):
  `transform --out x.h5` writes their composite with the landmark fit on top, which SimpleITK applies as `warpbench
  points` maps points, exactly outside the fixed volume too.
- `warpbench field --out x.h5` writes the field as ITK's DisplacementFieldTransform, pull-back or forward: SimpleITK
  applies it as the NIfTI field of the same run, and as `warpbench points` maps points; with another `--format` it is
  refused with exit 2, and nothing is written.

Needs SimpleITK and numpy, and the CLI binary (`conftest.py`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

sitk = pytest.importorskip("SimpleITK")

from conftest import run_cli as warpbench  # noqa: E402
from conftest import session_json  # noqa: E402
from test_ants_mat_sitk import pair  # noqa: E402


def affine(angle: float, translation: tuple, centre: tuple) -> "sitk.AffineTransform":
    rot = sitk.VersorRigid3DTransform()
    rot.SetRotation((0.3, -0.2, 1.0), angle)
    a = sitk.AffineTransform(3)
    m = np.array(rot.GetMatrix()).reshape(3, 3) @ np.diag([1.03, 0.98, 1.01])
    a.SetMatrix(tuple(m.flatten()))
    a.SetTranslation(translation)
    a.SetCenter(centre)
    return a


@pytest.mark.parametrize("kind", ["affines.h5", "euler.tfm", "rigid.h5"])
def test_initial_reads_simpleitks_linear_files_as_simpleitk_applies_them(tmp_path: Path, kind: str) -> None:
    fixed, moving = pair(tmp_path)
    composite = {
        "affines.h5": sitk.CompositeTransform([affine(0.1, (3.0, -2.0, 1.5), (5.0, -4.0, 2.0)),
                                               affine(-0.07, (-1.0, 0.5, 2.0), (-6.0, 3.0, 1.0))]),
        # What a SimpleITK rigid registration writes: an Euler3DTransform about the centre it was initialised on.
        "euler.tfm": sitk.Euler3DTransform((4.0, -6.0, 2.0), 0.05, -0.08, 0.12, (4.0, -3.0, 2.5)),
        "rigid.h5": sitk.VersorRigid3DTransform((0.2, 1.0, -0.3), 0.15, (1.0, 2.0, 3.0), (-2.0, 0.5, 1.0)),
    }[kind]
    h5 = tmp_path / kind
    sitk.WriteTransform(composite, str(h5))
    pairs = tmp_path / "two.csv"
    pairs.write_text('"Pt-0","true","1","2","3","1","2","3"\n"Pt-1","true","-10","5","0","-10","5","0"\n')
    points = [(12.5, -30.0, 8.0), (-20.0, 17.0, 25.0), (0.0, 0.0, 0.0)]
    targets = tmp_path / "targets.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
    out = tmp_path / "mapped.csv"
    warpbench("points", "--fixed", fixed, "--moving", moving, "--initial", h5, "--landmarks", pairs,
              "--from", "fixed", "--in", targets, "--out", out, "--quiet")
    mapped = [[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()]
    for got, p in zip(mapped, points):
        np.testing.assert_allclose(got, composite.TransformPoint(p), rtol=0, atol=1e-9)


def test_warp_field_resamples_through_an_ants_style_composite_as_simpleitk_does(tmp_path: Path) -> None:
    fixed_path, moving_path = pair(tmp_path)
    fixed = sitk.ReadImage(str(fixed_path))
    # A smooth field on the fixed grid, up to 3 mm, and an affine after it: x -> A(x + D(x)).
    k, j, i = np.meshgrid(*(np.arange(n, dtype=float) for n in reversed(fixed.GetSize())), indexing="ij")
    d = np.stack([3.0 * np.sin(i / 6.0), 2.0 * np.cos(j / 7.0) * np.sin(k / 9.0), 2.5 * np.sin((i + k) / 8.0)], -1)
    field = sitk.GetImageFromArray(d, isVector=True)
    field.CopyInformation(fixed)
    composite = sitk.CompositeTransform([affine(0.05, (2.0, -1.0, 0.5), (0.0, 0.0, 0.0)),
                                         sitk.DisplacementFieldTransform(field)])
    h5 = tmp_path / "Composite.h5"
    sitk.WriteTransform(composite, str(h5))
    out = tmp_path / "warped.nii.gz"
    warpbench("warp", "--fixed", fixed_path, "--moving", moving_path, "--field", h5, "--exact", "--out", out,
              "--quiet")
    ours = sitk.GetArrayFromImage(sitk.ReadImage(str(out))).astype(float)
    moving = sitk.ReadImage(str(moving_path))
    reference = sitk.Resample(moving, fixed, sitk.ReadTransform(str(h5)), sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    theirs = sitk.GetArrayFromImage(reference).astype(float)
    # Where the voxel's source lies well inside the moving volume (2 voxels from its edge), both sample the same
    # trilinear moving image at the same point, but for warpbench's field in f32 (1e-6 mm of a 3 mm vector): the
    # values differ by that times the image's steepest slope (below 100 a mm here), far under 0.01.
    inside = np.zeros(ours.shape, bool)
    index = np.argwhere(np.ones(ours.shape, bool))
    size = np.array(moving.GetSize())
    for (kk, jj, ii) in index:
        p = composite.TransformPoint(fixed.TransformIndexToPhysicalPoint((int(ii), int(jj), int(kk))))
        c = np.array(moving.TransformPhysicalPointToContinuousIndex(p))
        inside[kk, jj, ii] = bool(np.all(c >= 2) and np.all(c <= size - 3))
    assert inside.mean() > 0.5
    assert np.abs(ours - theirs)[inside].max() < 0.01
    assert np.abs(theirs[inside]).max() > 100  # the blobs are there to compare


def five_pairs(tmp_path: Path) -> Path:
    pairs = tmp_path / "pairs.csv"
    rows = [(10, -20, 15), (-30, 5, 0), (25, 30, -10), (0, -40, 30), (-15, 10, -25)]
    pairs.write_text("".join(f'"Pt-{n}","true",{x + 1},{y + 0.5},{z},{x},{y},{z}\n' for n, (x, y, z) in enumerate(rows)))
    return pairs


@pytest.mark.parametrize("how", ["affine", "hbspline", "align"])
def test_simpleitk_reads_the_h5_as_the_tfm_of_the_same_run(tmp_path: Path, how: str) -> None:
    fixed, moving = pair(tmp_path)
    read = {}
    for suffix in ("h5", "tfm"):
        out = tmp_path / f"t.{suffix}"
        if how == "align":
            warpbench("align", "--fixed", fixed, "--moving", moving, "--seed", "3", "--quiet", "--out-tfm", out)
        else:
            warpbench("transform", "--fixed", fixed, "--moving", moving, "--landmarks", five_pairs(tmp_path),
                      "--method", how, "--quiet", "--out", out)
        read[suffix] = sitk.ReadTransform(str(out))
    assert open(tmp_path / "t.h5", "rb").read(8) == b"\x89HDF\r\n\x1a\n"
    h5, tfm = read["h5"], read["tfm"]
    assert h5.GetName() == tfm.GetName() == ("BSplineTransform" if how == "hbspline" else "AffineTransform")
    assert h5.GetParameters() == tfm.GetParameters()
    assert h5.GetFixedParameters() == tfm.GetFixedParameters()
    for p in [(12.5, -30.0, 8.0), (-20.0, 17.0, 25.0), (0.0, 0.0, 0.0)]:
        assert h5.TransformPoint(p) == tfm.TransformPoint(p)


def test_simpleitk_applies_a_sessions_field_from_the_h5_as_warpbench_maps_points(tmp_path: Path) -> None:
    fixed_path, moving_path = pair(tmp_path)
    fixed = sitk.ReadImage(str(fixed_path))
    # A smooth field of up to 3 mm on a coarse grid over the fixed box, under two pairs: fewer than the TPS needs,
    # so the field alone is the warp (docs/cli.md, "A window session as the warp").
    coarse = sitk.Image([9, 9, 9], sitk.sitkVectorFloat64, 3)
    coarse.SetSpacing((10.0, 10.0, 10.0))
    coarse.SetOrigin((-40.0, -40.0, -40.0))
    k, j, i = np.meshgrid(*(np.arange(9, dtype=float) for _ in range(3)), indexing="ij")
    d = np.stack([3.0 * np.sin(j / 2.0), 2.0 * np.cos(i / 3.0), 1.5 * np.sin((i + k) / 4.0)], -1)
    field = sitk.GetImageFromArray(d, isVector=True)
    field.CopyInformation(coarse)
    field_path = tmp_path / "under.nii.gz"
    sitk.WriteImage(sitk.Cast(field, sitk.sitkVectorFloat32), str(field_path))
    session = tmp_path / "case.warpbench.json"
    landmarks = [{"name": "a", "active": True, "moving_lps": [1.0, 2.0, 3.0], "fixed_lps": [1.0, 2.0, 3.0]}]
    session.write_text(session_json(fixed_path, moving_path, landmarks=landmarks, field=str(field_path)))
    h5 = tmp_path / "with_field.h5"
    done = warpbench("transform", "--fixed", fixed_path, "--moving", moving_path, "--session", session, "--json",
                     "--quiet", "--out", h5)
    summary = json.loads(done.stdout)
    # Too few pairs to refine the field: the file is the session's field itself, on its own grid.
    assert summary["itk_class"] == "DisplacementFieldTransform_float_3_3", summary
    assert summary["members"] == ["DisplacementFieldTransform_float_3_3"], summary
    theirs = sitk.ReadTransform(str(h5))
    assert theirs.GetName() in ("DisplacementFieldTransform", "CompositeTransform")
    # Voxel centres of the fixed grid, where the field was sampled, and points between them.
    rng = np.random.default_rng(5)
    size = np.array(fixed.GetSize())
    indices = [tuple(int(v) for v in rng.integers(0, size)) for _ in range(20)]
    points = [fixed.TransformIndexToPhysicalPoint(ix) for ix in indices]
    points += [fixed.TransformContinuousIndexToPhysicalPoint(tuple(rng.uniform(2, size - 3))) for _ in range(20)]
    targets = tmp_path / "targets.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
    out = tmp_path / "mapped.csv"
    warpbench("points", "--fixed", fixed_path, "--moving", moving_path, "--session", session, "--from", "fixed",
              "--in", targets, "--out", out, "--quiet")
    ours = [[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()]
    moved = 0.0
    for p, at_centre, want in zip(points, [True] * 20 + [False] * 20, ours):
        got = theirs.TransformPoint(p)
        # Both interpolate the same coarse field's f32 vectors trilinearly, at voxel centres of the fixed grid and
        # between them (f32 geometry: 1e-6 of a few mm).
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5, err_msg=f"at {p} (a fixed voxel centre: {at_centre})")
        moved = max(moved, float(np.max(np.abs(np.array(got) - p))))
    assert moved > 0.5  # the field is there


def test_a_field_named_h5_is_the_transform_simpleitk_applies(tmp_path: Path) -> None:
    fixed_path, moving_path = pair(tmp_path)
    common = ["--fixed", fixed_path, "--moving", moving_path, "--landmarks", five_pairs(tmp_path), "--quiet"]
    for direction, grid_path, side in [("pullback", fixed_path, "fixed"), ("forward", moving_path, "moving")]:
        h5, nii = tmp_path / f"{direction}.h5", tmp_path / f"{direction}.nii.gz"
        for out in (h5, nii):
            warpbench("field", *common, "--direction", direction, "--out", out)
        theirs = sitk.ReadTransform(str(h5))
        # The same vectors as the NIfTI flavour of the same run, which SimpleITK reads as a field image.
        field = sitk.DisplacementFieldTransform(sitk.Cast(sitk.ReadImage(str(nii)), sitk.sitkVectorFloat64))
        grid = sitk.ReadImage(str(grid_path))
        rng = np.random.default_rng(11)
        size = np.array(grid.GetSize())
        points = [grid.TransformIndexToPhysicalPoint(tuple(int(v) for v in rng.integers(0, size))) for _ in range(30)]
        points += [grid.TransformContinuousIndexToPhysicalPoint(tuple(rng.uniform(1, size - 2))) for _ in range(30)]
        for p in points:
            np.testing.assert_allclose(theirs.TransformPoint(p), field.TransformPoint(p), rtol=0, atol=1e-9)
        # And the map warpbench means: fixed to moving for the pull-back, moving to fixed for the forward field.
        targets = tmp_path / f"{direction}_targets.csv"
        targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points[:30]))
        mapped = tmp_path / f"{direction}_mapped.csv"
        warpbench("points", *common, "--from", side, "--in", targets, "--out", mapped)
        ours = [[float(v) for v in line.split(",")[:3]] for line in mapped.read_text().splitlines()]
        for p, want in zip(points[:30], ours):
            # At the grid's voxel centres the file holds the map itself, in f32 (1e-6 of a few mm).
            np.testing.assert_allclose(theirs.TransformPoint(p), want, rtol=0, atol=1e-5, err_msg=f"{direction} {p}")


def test_a_field_named_h5_takes_the_default_flavour_only(tmp_path: Path) -> None:
    fixed, moving = pair(tmp_path)
    out = tmp_path / "field.h5"
    done = warpbench("field", "--fixed", fixed, "--moving", moving, "--landmarks", five_pairs(tmp_path), "--format",
                     "nrrd", "--out", out, expect=2)
    assert "HDF5 transform file" in done.stderr and out.name in done.stderr
    assert not out.exists()


@pytest.mark.parametrize("method", ["tps", "affine", "none"])
def test_the_h5_of_a_warp_on_simpleitks_bspline_result_is_their_composite(tmp_path: Path, method: str) -> None:
    """``transform --initial T --initial-field R.tfm --out x.h5`` over SimpleITK's B-spline result (an affine and a
    B-spline in a composite ``.tfm``): the file is ITK's composite [T, R's members, the landmark fit], which
    SimpleITK applies as ``warpbench points`` maps points. T and R's members are the transforms themselves, so they
    act exactly everywhere, outside the fixed volume too. The fit over them is itself where ITK holds it (an affine;
    with no pairs there is none), and a TPS is its field on the fixed grid: exact at the grid's voxel centres (f32),
    and the identity outside the grid, where the rest still acts."""
    from conftest import FIXED, MOVING  # noqa: PLC0415

    fixed = sitk.ReadImage(str(FIXED))
    b = sitk.BSplineTransformInitializer(fixed, [3, 3, 3], 3)
    rng = np.random.default_rng(11)
    b.SetParameters(tuple(float(v) for v in rng.uniform(-1.5, 1.5, len(b.GetParameters()))))
    a = affine(0.04, (0.8, -0.5, 0.3), (1.0, 2.0, -1.0))
    result = tmp_path / "sitk_result.tfm"
    sitk.WriteTransform(sitk.CompositeTransform([a, b]), str(result))
    start = tmp_path / "start.tfm"
    t = affine(-0.03, (1.5, 0.5, -1.0), (0.0, 0.0, 0.0))
    sitk.WriteTransform(t, str(start))
    pairs = tmp_path / "pairs.csv"
    # At voxel centres of the fixed grid (origin (-15, -13, -11) mm, 2 mm voxels), where a sampled fit is exact.
    fixed_points = [(-7.0, 5.0, 3.0), (7.0, -5.0, -3.0), (1.0, 9.0, -5.0), (-5.0, -7.0, 7.0), (5.0, 3.0, 5.0)]
    composite = sitk.CompositeTransform([t, a, b])
    rows = []
    for n, q in enumerate(fixed_points):
        p = np.array(composite.TransformPoint(q)) + rng.uniform(-1.5, 1.5, 3)
        rows.append(f'"Pt-{n}","true",' + ",".join(f'"{float(v)!r}"' for v in (*p, *q)))
    pairs.write_text("\n".join(rows if method != "none" else []) + "\n")
    h5 = tmp_path / "result.h5"
    args = ["--fixed", FIXED, "--moving", MOVING, "--initial", start, "--initial-field", result, "--landmarks", pairs]
    if method != "none":
        args += ["--method", method]
    summary = json.loads(warpbench("transform", *args, "--json", "--quiet", "--out", h5).stdout)
    members = ["AffineTransform_double_3_3", "AffineTransform_double_3_3", "BSplineTransform_double_3_3"]
    members += {"tps": ["DisplacementFieldTransform_float_3_3"], "affine": ["AffineTransform_double_3_3"],
                "none": []}[method]
    assert summary["itk_class"] == "CompositeTransform_double_3_3" and summary["members"] == members, summary
    theirs = sitk.ReadTransform(str(h5))
    assert theirs.GetName() == "CompositeTransform" and theirs.GetNumberOfTransforms() == len(members)

    # Voxel centres of the fixed grid, and points far outside it (where the B-spline is the identity too).
    size = np.array(fixed.GetSize())
    centres = [tuple(int(v) for v in rng.integers(0, size)) for _ in range(30)]
    inside = [fixed.TransformIndexToPhysicalPoint(ix) for ix in centres] + fixed_points
    outside = [(60.0, -40.0, 25.0), (-45.0, 50.0, -70.0)]
    targets = tmp_path / "targets.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in inside + outside))
    out = tmp_path / "mapped.csv"
    warpbench("points", *args, "--from", "fixed", "--in", targets, "--out", out, "--quiet")
    ours = [[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()]
    # The TPS's field holds f32 vectors of a few mm; the affine and the B-spline are the same doubles.
    bound = 1e-5 if method == "tps" else 1e-9
    for p, want in zip(inside, ours):
        np.testing.assert_allclose(theirs.TransformPoint(p), want, rtol=0, atol=bound, err_msg=f"at {p}")
    for p, want in zip(outside, ours[len(inside):]):
        if method == "tps":
            # The fit's field is the identity outside the fixed grid: there the file is T ∘ A ∘ B.
            want = composite.TransformPoint(p)
        np.testing.assert_allclose(theirs.TransformPoint(p), want, rtol=0, atol=1e-9, err_msg=f"at {p}")
    # Python writes the same file from a warp fitted on the same inputs.
    import warpbench as wb  # noqa: PLC0415

    landmarks = wb.read_landmarks(pairs) if method != "none" else wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    volumes = {"fixed": wb.read_volume(FIXED), "moving": wb.read_volume(MOVING)}
    fitted = wb.fit(landmarks, method if method != "none" else "tps", initial=start, initial_field=result, **volumes)
    from_python = tmp_path / "python.h5"
    fitted.to_itk_tfm(from_python)
    assert from_python.read_bytes() == h5.read_bytes()
    if method == "tps":
        with pytest.raises(ValueError, match="python.tfm: .*name the file .h5"):
            fitted.to_itk_tfm(tmp_path / "python.tfm")
        bare = wb.fit(landmarks, initial=start, initial_field=result)
        with pytest.raises(ValueError, match="sampled on the fixed grid: fit with fixed= and moving="):
            bare.to_itk_tfm(tmp_path / "bare.h5")
    if method == "tps":
        # The interpolating TPS keeps each fixed landmark on its moving partner, in the file too.
        for q, row in zip(fixed_points, rows):
            p = [float(v.strip('"')) for v in row.split(",")[2:5]]
            np.testing.assert_allclose(theirs.TransformPoint(q), p, rtol=0, atol=bound)
