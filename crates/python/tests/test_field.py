"""`read_field`: every flavour `--field` reads, against SimpleITK's reading of the same files and elastix's own.

- transformix's field (`tests/data/metaimage/transformix_field.mhd`, written by itk-elastix 0.25.4) reads to the
  array and grid SimpleITK reads from it (numpy's k-j-i order turned to i-j-k);
- the elastix parameter file transformix made it from (`tests/data/elastix/bspline_oblique.txt`) reads, sampled on
  its fixed grid, to the same field within f32 rounding (1e-6 mm), but for the voxels on the edge of the B-spline's
  region, where transformix breaks a tie by rounding (`crates/io/tests/elastix.rs`);
- ITK's HDF5 transform file of an affine and a displacement field (`tests/data/itk/h5_composite.h5`, written by
  SimpleITK as antsRegistration writes `Composite.h5`) reads to the field SimpleITK's TransformToDisplacementField
  makes of it on the field's grid, within f32 rounding;
- a field written by `Warp.field` in each flavour reads back to the same vectors and names its flavour, and one
  named `.h5` is ITK's HDF5 transform file, which SimpleITK applies as x + D(x);
- `Warp.jacobian` is the limit of SimpleITK's finite-difference Jacobian determinant, and the CLI's map.
"""

from __future__ import annotations

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA, FIXED, MOVING, PAIRS, T1, run_cli

sitk = pytest.importorskip("SimpleITK")

TRANSFORMIX = DATA / "metaimage" / "transformix_field.mhd"
ELASTIX = DATA / "elastix" / "bspline_oblique.txt"


def sitk_field(path):
    image = sitk.ReadImage(str(path))
    vectors = sitk.GetArrayFromImage(image).transpose(2, 1, 0, 3)  # k-j-i-c to i-j-k-c
    direction = np.array(image.GetDirection()).reshape(3, 3)
    lps = np.eye(4)
    lps[:3, :3] = direction * np.array(image.GetSpacing())
    lps[:3, 3] = image.GetOrigin()
    return vectors, lps


def test_transformix_field_reads_as_simpleitk_reads_it():
    field = wb.read_field(TRANSFORMIX)
    vectors, lps = sitk_field(TRANSFORMIX)
    assert field.source == "metaimage" and field.direction is None
    assert field.shape == vectors.shape[:3] and field.array.dtype == np.float32
    np.testing.assert_array_equal(field.array, vectors)
    np.testing.assert_allclose(field.lps_from_index, lps, atol=1e-12)


def test_an_elastix_parameter_file_reads_as_the_field_transformix_wrote():
    ours = wb.read_field(ELASTIX)
    vectors, lps = sitk_field(TRANSFORMIX)
    assert ours.source == "elastix" and ours.direction is None
    np.testing.assert_allclose(ours.lps_from_index, lps, atol=1e-12)
    inner = (slice(1, None), slice(1, None), slice(1, None))
    np.testing.assert_allclose(ours.array[inner], vectors[inner], rtol=0, atol=1e-6)
    assert np.abs(vectors).max() > 0.5


def test_an_itk_h5_composite_reads_as_simpleitk_samples_it():
    path = DATA / "itk" / "h5_composite.h5"
    ours = wb.read_field(path)
    assert ours.source == "itk_h5" and ours.direction == "pullback"
    transform = sitk.ReadTransform(str(path))
    inner = sitk.CompositeTransform(transform).GetNthTransform(1)
    grid = sitk.DisplacementFieldTransform(inner).GetDisplacementField()
    sampled = sitk.TransformToDisplacementField(transform, sitk.sitkVectorFloat64, grid.GetSize(), grid.GetOrigin(),
                                                grid.GetSpacing(), grid.GetDirection())
    vectors = sitk.GetArrayFromImage(sampled).transpose(2, 1, 0, 3)
    direction = np.array(grid.GetDirection()).reshape(3, 3)
    lps = np.eye(4)
    lps[:3, :3] = direction * np.array(grid.GetSpacing())
    lps[:3, 3] = grid.GetOrigin()
    np.testing.assert_allclose(ours.lps_from_index, lps, atol=1e-12)
    np.testing.assert_allclose(ours.array, vectors, rtol=0, atol=1e-5)
    assert np.abs(vectors).max() > 2.0


def test_slicers_inverse_field_is_the_forward_field_it_holds():
    """3D Slicer's InverseDisplacementFieldTransform (SimpleITK's h5_field.h5 under Slicer's class,
    data-scripts/slicer_transforms.py), which SimpleITK cannot read, is read as a forward field: the vectors SimpleITK
    reads from the plain file, on its grid."""
    path = DATA / "itk" / "h5_field_slicer_inverse.h5"
    with pytest.raises(RuntimeError):
        sitk.ReadTransform(str(path))
    ours = wb.read_field(path)
    assert ours.source == "itk_h5" and ours.direction == "forward"
    grid = sitk.DisplacementFieldTransform(sitk.ReadTransform(str(DATA / "itk" / "h5_field.h5"))).GetDisplacementField()
    vectors = sitk.GetArrayFromImage(grid).transpose(2, 1, 0, 3)
    np.testing.assert_allclose(ours.array, vectors, rtol=0, atol=1e-6)
    lps = np.eye(4)
    lps[:3, :3] = np.array(grid.GetDirection()).reshape(3, 3) * np.array(grid.GetSpacing())
    lps[:3, 3] = grid.GetOrigin()
    np.testing.assert_allclose(ours.lps_from_index, lps, atol=1e-12)


def test_a_written_field_reads_back_in_every_flavour(tmp_path):
    head = wb.read_volume(T1)
    warp = wb.fit(wb.read_landmarks(PAIRS), "tps", fixed=head, moving=head)
    for fmt, name in [("itk", "f.nii.gz"), ("ants", "a.nii.gz"), ("nrrd", "f.nrrd"), ("metaimage", "f.mha")]:
        sampled = warp.field(path=tmp_path / name, format=fmt)
        back = wb.read_field(tmp_path / name)
        assert back.source == fmt
        assert back.direction == ("pullback" if fmt == "nrrd" else None)
        np.testing.assert_allclose(back.array, sampled, rtol=0, atol=1e-6 if fmt == "itk" else 0)
        np.testing.assert_allclose(back.lps_from_index, head.lps_from_index, atol=1e-4)
    # ITK's HDF5 transform file: the field as a DisplacementFieldTransform, read back by warpbench and SimpleITK.
    sampled = warp.field(path=tmp_path / "f.h5")
    back = wb.read_field(tmp_path / "f.h5")
    assert (back.source, back.direction) == ("itk_h5", "pullback")
    np.testing.assert_array_equal(back.array, sampled)
    theirs = sitk.ReadTransform(str(tmp_path / "f.h5"))
    x = head.lps_from_index @ np.array([40.0, 50.0, 30.0, 1.0])
    np.testing.assert_allclose(theirs.TransformPoint(tuple(x[:3])), x[:3] + sampled[40, 50, 30], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="HDF5 transform file"):
        warp.field(path=tmp_path / "n.h5", format="nrrd")
    assert not (tmp_path / "n.h5").exists()


def test_what_is_not_a_field_is_a_value_error_naming_it(tmp_path):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello\n")
    with pytest.raises(ValueError, match="notes.txt"):
        wb.read_field(bad)
    with pytest.raises(OSError):
        wb.read_field(tmp_path / "missing.nii.gz")


def _sitk_det(field: np.ndarray, lps: np.ndarray) -> np.ndarray:
    """SimpleITK's DisplacementFieldJacobianDeterminant of (ni, nj, nk, 3) LPS vectors on an axis-aligned grid."""
    image = sitk.GetImageFromArray(field.transpose(2, 1, 0, 3).astype(np.float64), isVector=True)
    image.SetSpacing(tuple(np.diag(lps)[:3]))
    image.SetOrigin(tuple(lps[:3, 3]))
    return sitk.GetArrayFromImage(sitk.DisplacementFieldJacobianDeterminant(image)).transpose(2, 1, 0)


def test_jacobian_is_the_limit_of_simpleitks_finite_differences_and_the_clis_map(tmp_path):
    """``Warp.jacobian`` against a peer: SimpleITK's ``DisplacementFieldJacobianDeterminant`` of the field
    ``Warp.field`` samples, on a 20 mm cube 23 mm from the nearest landmark at spacings h = 2, 0.5 and 0.25 mm (the
    interior voxels). ITK differentiates by central differences, off by h²/6 · |∂³u|; warpbench differentiates the
    warp itself. So their gap must shrink like h² (to under a quarter from 2 to 0.5 mm; 1/16 in exact arithmetic)
    and at 0.25 mm be within f32's rounding of central differences: displacements under 8 mm carry 5e-7 mm, over
    2h = 0.5 mm that is 2e-6 an entry, under 2e-5 in the determinant. Both the TPS and the B-spline. The map
    equals the CLI's ``warpbench jacobian`` output, and ``quantity="magnitude"`` is |u(x) − x|."""
    head = wb.read_volume(T1)
    pairs = wb.read_landmarks(PAIRS)
    for method in ["tps", "hbspline"]:
        warp = wb.fit(pairs, method, fixed=head, moving=head)
        gap = {}
        for h in [2.0, 0.5, 0.25]:
            n = int(round(20 / h))
            lps = np.diag([h, h, h, 1.0])
            lps[:3, 3] = [-10.0, -10.0, -5.0]
            reference = wb.Volume.from_array(np.zeros((n, n, n), dtype=np.float32), lps)
            ours = warp.jacobian(reference)
            assert ours.shape == (n, n, n) and ours.dtype == np.float32
            theirs = _sitk_det(warp.field(reference), lps)
            inner = (slice(1, -1),) * 3
            gap[h] = np.abs(ours[inner] - theirs[inner]).max()
            assert np.ptp(ours) > 0.05, "the warp's det varies over the cube"
        assert gap[2.0] > 4 * gap[0.5], (method, gap)
        assert gap[0.25] < 2e-5, (method, gap)
        # The forward map's det ∇d against ITK's differences of the forward field, at the finest spacing.
        forward = warp.jacobian(reference, direction="forward")
        theirs = _sitk_det(warp.field(reference, direction="forward"), lps)
        assert np.abs(forward[inner] - theirs[inner]).max() < 2e-5, method
        assert np.ptp(forward) > 0.05, "the forward map's det varies over the cube"

    warp = wb.fit(pairs, "tps", fixed=head, moving=head)
    out = tmp_path / "det.nii.gz"
    run_cli("jacobian", "--fixed", T1, "--moving", T1, "--landmarks", PAIRS, "--out", out, "--quiet")
    np.testing.assert_array_equal(warp.jacobian(), wb.read_volume(out).array)
    out = tmp_path / "det_forward.nii.gz"
    run_cli("jacobian", "--fixed", T1, "--moving", T1, "--landmarks", PAIRS, "--direction", "forward", "--out", out,
            "--quiet")
    np.testing.assert_array_equal(warp.jacobian(direction="forward"), wb.read_volume(out).array)
    moved = warp.jacobian(head, quantity="magnitude", path=tmp_path / "moved.nrrd")
    np.testing.assert_allclose(moved, np.linalg.norm(warp.field(head), axis=-1), rtol=0, atol=1e-5)
    np.testing.assert_array_equal(wb.read_volume(tmp_path / "moved.nrrd").array, moved)
    with pytest.raises(ValueError, match="give det or magnitude"):
        warp.jacobian(head, quantity="volume")
    with pytest.raises(ValueError, match="give pullback or forward"):
        warp.jacobian(head, direction="backward")


def test_initial_field_lies_under_initial_as_itks_composite_applies_them(tmp_path):
    """``fit(initial_field=, initial=)`` and ``points --initial-field --initial`` with no pairs map a fixed point x to
    A(F(x)), the field first, as SimpleITK's ``CompositeTransform([A, F])`` (ANTs' ``-t FIELD -t AFFINE``) maps it:
    inside the oblique field's grid and outside it, where F is the identity. With pairs on top, the landmark fit
    keeps each fixed landmark on its moving partner."""
    field_path = DATA / "itk" / "field_input_field_sitk.nii.gz"
    displacement = sitk.DisplacementFieldTransform(sitk.Cast(sitk.ReadImage(str(field_path)), sitk.sitkVectorFloat64))
    affine = sitk.AffineTransform(3)
    affine.SetMatrix((0.98, -0.1, 0.02, 0.09, 1.01, -0.04, -0.03, 0.05, 0.99))
    affine.SetTranslation((2.5, -1.0, 3.0))
    affine.SetCenter((1.0, -2.0, 0.5))
    tfm = tmp_path / "affine.tfm"
    sitk.WriteTransform(affine, str(tfm))
    composite = sitk.CompositeTransform([affine, displacement])
    points = np.array([[0.0, 0.0, 0.0], [-5.5, 3.25, 2.0], [4.0, -6.0, -3.5], [40.0, 30.0, -25.0], [-2.0, 9.0, 6.0]])
    want = np.array([composite.TransformPoint(tuple(p)) for p in points])
    moved = np.array([displacement.TransformPoint(tuple(p)) for p in points])
    assert np.abs(moved - points).max() > 1.0, "the points feel the field"

    none = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(none, initial=tfm, initial_field=field_path)
    # ITK's field reads its f32 vectors and f32 sform into doubles as warpbench does: agreement to f32 geometry.
    np.testing.assert_allclose(warp.pullback(points), want, rtol=0, atol=1e-4)
    assert "field_input_field_sitk.nii.gz" in warp.method

    targets, out = tmp_path / "targets.csv", tmp_path / "mapped.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points.tolist()))
    empty = tmp_path / "none.csv"
    empty.write_text("")
    run_cli("points", "--fixed", FIXED, "--moving", MOVING, "--initial", tfm, "--initial-field", field_path,
            "--landmarks", empty, "--from", "fixed", "--in", targets, "--out", out, "--quiet")
    got = np.array([[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)

    # Pairs on top of the two: each fixed landmark maps onto its moving partner.
    fixed_points = points[:4] * 0.5
    moving_points = np.array([composite.TransformPoint(tuple(q)) for q in fixed_points]) + [[1.5, 0, 0], [0, -2, 0],
                                                                                           [0, 0, 1], [1, 1, -1]]
    on_top = wb.fit(wb.Pairs(moving_points, fixed_points), initial=tfm, initial_field=field_path)
    np.testing.assert_allclose(on_top.pullback(fixed_points), moving_points, rtol=0, atol=1e-6)


def test_a_field_object_lies_under_the_landmarks(tmp_path):
    """``fit(initial_field=Field)``: a field read with :func:`read_field` lies under the landmarks as its file does,
    point for point; one made from an array is the pull-back x + D(x) on its grid (a constant D, which trilinear
    interpolation holds exactly) and the identity outside it, or with ``direction="forward"`` the map it inverts.
    A malformed one is a ValueError naming ``initial_field``."""
    field_path = DATA / "itk" / "field_input_field_sitk.nii.gz"
    displacement = sitk.DisplacementFieldTransform(sitk.Cast(sitk.ReadImage(str(field_path)), sitk.sitkVectorFloat64))
    points = np.array([[0.0, 0.0, 0.0], [-5.5, 3.25, 2.0], [4.0, -6.0, -3.5], [40.0, 30.0, -25.0]])
    want = np.array([displacement.TransformPoint(tuple(p)) for p in points])
    none = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    from_file = wb.fit(none, initial_field=field_path)
    from_field = wb.fit(none, initial_field=wb.read_field(field_path))
    np.testing.assert_array_equal(from_field.pullback(points), from_file.pullback(points))
    np.testing.assert_allclose(from_field.pullback(points), want, rtol=0, atol=1e-4)

    # A constant displacement on an oblique 6×5×4 grid of 2 mm voxels about the origin.
    c, s_ = np.cos(0.3), np.sin(0.3)
    lps = np.eye(4)
    lps[:3, :3] = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]) * 2.0
    lps[:3, 3] = -lps[:3, :3] @ np.array([2.5, 2.0, 1.5])
    d = np.array([1.25, -0.5, 0.75])
    array = np.broadcast_to(d.astype(np.float32), (6, 5, 4, 3)).copy()
    inside = np.array([[0.0, 0.0, 0.0], [1.0, -1.5, 0.5], [-2.0, 1.0, -1.0]])
    outside = np.array([[30.0, 0.0, 0.0], [0.0, -25.0, 12.0]])
    pullback = wb.fit(none, initial_field=wb.Field(array, lps, "numpy", None))
    np.testing.assert_allclose(pullback.pullback(inside), inside + d, rtol=0, atol=1e-6)
    np.testing.assert_allclose(pullback.pullback(outside), outside, rtol=0, atol=0)
    forward = wb.fit(none, initial_field=wb.Field(array, lps, "numpy", "forward"))
    np.testing.assert_allclose(forward.pullback(inside + d), inside, rtol=0, atol=1e-5)
    np.testing.assert_allclose(forward.forward(inside), inside + d, rtol=0, atol=1e-6)
    # Pairs on top keep each fixed landmark on its moving partner.
    fixed_points = np.array([[0.5, 0.5, 0.0], [-1.5, 1.0, 0.5], [1.0, -2.0, -0.5], [2.0, 2.0, 1.0]])
    moving_points = fixed_points + d + [[0.5, 0, 0], [0, -0.5, 0], [0, 0, 0.25], [0, 0, 0]]
    on_top = wb.fit(wb.Pairs(moving_points, fixed_points), initial_field=wb.Field(array, lps, "numpy", None))
    np.testing.assert_allclose(on_top.pullback(fixed_points), moving_points, rtol=0, atol=1e-6)

    bad = [
        (wb.Field(array[..., :2], lps, "numpy", None), r"initial_field: .*\(ni, nj, nk, 3\)"),
        (wb.Field(array, lps[:3], "numpy", None), r"initial_field: .*4×4"),
        (wb.Field(np.full_like(array, np.nan), lps, "numpy", None), r"initial_field: .*not finite"),
        (wb.Field(array, np.zeros((4, 4)), "numpy", None), r"initial_field: .*singular"),
        (wb.Field(array, lps, "numpy", "backward"), r"initial_field: direction 'backward'"),
    ]
    for field, message in bad:
        with pytest.raises(ValueError, match=message):
            wb.fit(none, initial_field=field)
    # The commands take files: a Field there is refused before anything runs.
    with pytest.raises(ValueError, match="initial_field: the command takes a file, not a Field"):
        wb.register(FIXED, MOVING, initial_field=wb.read_field(field_path))


def test_a_learn2reg_initial_field_needs_the_volumes(tmp_path):
    """A Learn2Reg ``.npz`` under the landmarks is read against ``fixed`` and ``moving``; without them it is a
    ValueError naming the file."""
    npz = DATA / "learn2reg" / "disp_2021.npz"
    none = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="disp_2021.npz.*fixed= and moving="):
        wb.fit(none, initial_field=npz)


def _bspline_composite(fixed_path):
    """SimpleITK's composite of an affine A and a cubic B-spline B over the fixed image's domain, with seeded
    coefficients of up to 2 mm: what its B-spline registration examples write."""
    fixed = sitk.ReadImage(str(fixed_path))
    b = sitk.BSplineTransformInitializer(fixed, [3, 3, 3], 3)
    rng = np.random.default_rng(7)
    b.SetParameters(tuple(float(v) for v in rng.uniform(-2.0, 2.0, len(b.GetParameters()))))
    a = sitk.AffineTransform(3)
    a.SetMatrix((1.01, 0.03, 0.0, -0.02, 0.99, 0.01, 0.0, 0.02, 1.0))
    a.SetTranslation((0.8, -0.5, 0.3))
    return a, b, sitk.CompositeTransform([a, b])


def test_an_itk_bspline_transform_is_a_field_on_the_fixed_grid(tmp_path):
    """A composite ``.tfm`` of an affine and a B-spline, as SimpleITK writes it, and a B-spline alone in an ``.h5``
    (as 3D Slicer saves one), give no grid of their own: ``warp --field`` samples them on the output grid and
    resamples as SimpleITK's ``Resample`` does through the transform; ``read_field(path, fixed, moving)`` is
    SimpleITK's ``TransformToDisplacementField`` on the fixed grid; ``--initial-field`` and
    ``fit(initial_field=...)`` put them under the landmarks as they are, mapping points as ``TransformPoint`` does,
    outside the fixed volume too (where the affine still acts)."""
    a, b, composite = _bspline_composite(FIXED)
    tfm, h5 = tmp_path / "result.tfm", tmp_path / "bspline.h5"
    sitk.WriteTransform(composite, str(tfm))
    sitk.WriteTransform(b, str(h5))
    fixed, moving = sitk.ReadImage(str(FIXED)), sitk.ReadImage(str(MOVING), sitk.sitkFloat32)

    # The warped volume, exact at every output voxel.
    for path, transform in ((tfm, composite), (h5, b)):
        out = tmp_path / f"warped_{path.suffix[1:]}.nii.gz"
        run_cli("warp", "--fixed", FIXED, "--moving", MOVING, "--field", path, "--exact", "--backend", "cpu",
                "--out", out, "--quiet")
        want = sitk.GetArrayFromImage(sitk.Resample(moving, fixed, transform, sitk.sitkLinear, 0.0, sitk.sitkFloat32))
        got = sitk.GetArrayFromImage(sitk.ReadImage(str(out)))
        # The sampled vectors are f32 (1e-6 mm); the moving volume changes by at most ~60 per mm.
        assert np.abs(got - want).max() < 1e-3 * max(1.0, np.abs(want).max()), path.name

    # The field on the fixed grid.
    field = wb.read_field(tfm, fixed=wb.read_volume(FIXED), moving=wb.read_volume(MOVING))
    assert (field.source, field.direction) == ("itk_tfm", "pullback")
    sitk_field = sitk.TransformToDisplacementField(composite, sitk.sitkVectorFloat64, fixed.GetSize(),
                                                   fixed.GetOrigin(), fixed.GetSpacing(), fixed.GetDirection())
    want = sitk.GetArrayFromImage(sitk_field).transpose(2, 1, 0, 3)
    np.testing.assert_allclose(field.array, want, rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="result.tfm.*no grid"):
        wb.read_field(tfm)

    # Under the landmarks, with no pairs: the transforms themselves, at any point (the last two outside the fixed
    # volume, where B is the identity and A still acts).
    fixed_volume = wb.read_volume(FIXED)
    lps = fixed_volume.lps_from_index
    centres = np.array([[3.5, 4, 5], [8, 7.25, 6], [12, 9, 4.5], [5, 10, 8], [-30, 5, 2], [40, -20, 30]])
    points = (lps[:3, :3] @ centres.T).T + lps[:3, 3]
    want = np.array([b.TransformPoint(tuple(p)) for p in points])
    assert np.abs(want - points).max() > 0.5, "the points feel the B-spline"
    none = wb.Pairs(np.zeros((0, 3)), np.zeros((0, 3)))
    warp = wb.fit(none, initial_field=h5, fixed=fixed_volume, moving=wb.read_volume(MOVING))
    np.testing.assert_allclose(warp.pullback(points), want, rtol=0, atol=1e-9)
    through_tfm = wb.fit(none, initial_field=tfm)
    want_composite = np.array([composite.TransformPoint(tuple(p)) for p in points])
    np.testing.assert_allclose(through_tfm.pullback(points), want_composite, rtol=0, atol=1e-9)
    # The forward map inverts it by Newton's method, to its 1e-6 mm.
    np.testing.assert_allclose(through_tfm.forward(want_composite), points, rtol=0, atol=1e-5)
    targets, out = tmp_path / "targets.csv", tmp_path / "mapped.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points.tolist()))
    empty = tmp_path / "none.csv"
    empty.write_text("")
    run_cli("points", "--fixed", FIXED, "--moving", MOVING, "--initial-field", h5, "--landmarks", empty,
            "--from", "fixed", "--in", targets, "--out", out, "--quiet")
    got = np.array([[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
