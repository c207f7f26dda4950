"""The ANTs / ITK affine `.mat` (MATLAB v4) between warpbench and SimpleITK.

- `warpbench align --out-tfm x.mat` and `--out-tfm x.tfm`, the same run (same inputs and seed, which give the same
  result): SimpleITK's ReadTransform of the `.mat` is the `.tfm`'s transform, parameter for parameter, and maps
  points the same way; its class is SimpleITK's AffineTransform.
- SimpleITK writes an affine (with a centre) to `.mat` and to `.tfm`: `warpbench points --initial` with either
  (too few pairs to refine it, so it alone is the warp) maps points where SimpleITK's TransformPoint puts them.

Needs SimpleITK and numpy, and the CLI binary (`conftest.py`: `WARPBENCH_BIN`, default
`<repo>/target/debug/warpbench`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

sitk = pytest.importorskip("SimpleITK")

from conftest import run_cli as warpbench  # noqa: E402


def blobs(path: Path) -> "sitk.Image":
    """A 40³ float volume of a few Gaussian blobs of different sizes and heights (structure for mutual information),
    2 mm voxels centred on the origin."""
    n = 40
    k, j, i = np.meshgrid(*(np.arange(n, dtype=float) for _ in range(3)), indexing="ij")
    x = np.stack([i, j, k], axis=-1) * 2.0 - (n - 1)
    values = np.zeros((n, n, n))
    for centre, sigma, height in [((-12, 5, 3), 7, 800), ((14, -8, -6), 5, 500), ((3, 15, -14), 4, 1000),
                                  ((-5, -16, 12), 6, 650), ((0, 0, 0), 14, 200)]:
        values += height * np.exp(-np.sum((x - np.array(centre)) ** 2, axis=-1) / (2 * sigma**2))
    img = sitk.GetImageFromArray(values.astype(np.float32))
    img.SetSpacing((2.0, 2.0, 2.0))
    img.SetOrigin((-(n - 1.0), -(n - 1.0), -(n - 1.0)))
    sitk.WriteImage(img, str(path))
    return img


def pair(tmp_path: Path) -> tuple[Path, Path]:
    """The blobs, and the blobs moved by a known rigid transform (resampled by SimpleITK)."""
    fixed_path, moving_path = tmp_path / "fixed.nii.gz", tmp_path / "moving.nii.gz"
    fixed = blobs(fixed_path)
    truth = sitk.Euler3DTransform((0.0, 0.0, 0.0), 0.05, -0.08, 0.12, (4.0, -3.0, 2.5))
    moving = sitk.Resample(fixed, fixed, truth, sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    sitk.WriteImage(moving, str(moving_path))
    return fixed_path, moving_path


def test_simpleitk_reads_the_mat_align_writes_as_the_tfm_of_the_same_run(tmp_path: Path) -> None:
    fixed, moving = pair(tmp_path)
    mat, tfm = tmp_path / "start.mat", tmp_path / "start.tfm"
    for out in (mat, tfm):
        warpbench("align", "--fixed", fixed, "--moving", moving, "--affine", "--seed", "7", "--quiet",
                  "--out-tfm", out)
    from_mat = sitk.ReadTransform(str(mat))
    from_tfm = sitk.ReadTransform(str(tfm))
    assert from_mat.GetName() == from_tfm.GetName() == "AffineTransform"
    assert from_mat.GetParameters() == from_tfm.GetParameters()
    assert from_mat.GetFixedParameters() == from_tfm.GetFixedParameters()
    assert any(abs(p - q) > 1e-3 for p, q in zip(from_mat.GetParameters(), (1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0)))
    for p in [(0.0, 0.0, 0.0), (12.5, -30.0, 8.0), (-20.0, 17.0, 25.0)]:
        assert from_mat.TransformPoint(p) == from_tfm.TransformPoint(p)


def test_initial_reads_simpleitks_mat_as_simpleitk_applies_it(tmp_path: Path) -> None:
    fixed, moving = pair(tmp_path)
    affine = sitk.AffineTransform(3)
    affine.SetMatrix((0.99, -0.12, 0.01, 0.11, 0.98, -0.05, -0.02, 0.06, 1.03))
    affine.SetTranslation((3.0, -2.0, 1.5))
    affine.SetCenter((5.0, -4.0, 2.0))
    mat, tfm = tmp_path / "sitk.mat", tmp_path / "sitk.tfm"
    sitk.WriteTransform(affine, str(mat))
    sitk.WriteTransform(affine, str(tfm))
    # Two pairs: fewer than the TPS needs, so the starting transform alone is the warp.
    pairs = tmp_path / "two.csv"
    pairs.write_text('"Pt-0","true","1","2","3","1","2","3"\n"Pt-1","true","-10","5","0","-10","5","0"\n')
    points = [(12.5, -30.0, 8.0), (-20.0, 17.0, 25.0), (0.0, 0.0, 0.0)]
    targets = tmp_path / "targets.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
    mapped = {}
    for initial in (mat, tfm):
        out = tmp_path / f"mapped_{initial.suffix[1:]}.csv"
        warpbench("points", "--fixed", fixed, "--moving", moving, "--initial", initial, "--landmarks", pairs,
                  "--from", "fixed", "--in", targets, "--out", out, "--quiet")
        mapped[initial.suffix] = [[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()]
    assert mapped[".mat"] == mapped[".tfm"]
    for got, p in zip(mapped[".mat"], points):
        np.testing.assert_allclose(got, affine.TransformPoint(p), rtol=0, atol=1e-9)


def test_initial_reads_a_composite_tfm_of_linear_transforms_as_simpleitk_applies_it(tmp_path: Path) -> None:
    """SimpleITK writes a registration's result as a composite ``.tfm`` (an Euler start under a similarity, say):
    ``--initial`` composes its members as ITK does, the last first, and maps points where SimpleITK's
    ``TransformPoint`` does; a composite with a B-spline is refused there, saying where it goes."""
    fixed, moving = pair(tmp_path)
    euler = sitk.Euler3DTransform((5.0, -4.0, 2.0), 0.05, -0.1, 0.2, (2.0, -1.0, 3.5))
    similarity = sitk.Similarity3DTransform()
    similarity.SetScale(1.04)
    similarity.SetRotation((0.0, 0.0, 1.0), 0.15)
    similarity.SetTranslation((-1.5, 2.0, 0.5))
    composite = sitk.CompositeTransform([similarity, euler])
    tfm = tmp_path / "composite.tfm"
    sitk.WriteTransform(composite, str(tfm))
    assert "CompositeTransform" in tfm.read_text()
    pairs = tmp_path / "two.csv"
    pairs.write_text('"Pt-0","true","1","2","3","1","2","3"\n"Pt-1","true","-10","5","0","-10","5","0"\n')
    points = [(12.5, -30.0, 8.0), (-20.0, 17.0, 25.0), (0.0, 0.0, 0.0)]
    targets, out = tmp_path / "targets.csv", tmp_path / "mapped.csv"
    targets.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
    warpbench("points", "--fixed", fixed, "--moving", moving, "--initial", tfm, "--landmarks", pairs,
              "--from", "fixed", "--in", targets, "--out", out, "--quiet")
    got = [[float(v) for v in line.split(",")[:3]] for line in out.read_text().splitlines()]
    for g, p in zip(got, points):
        np.testing.assert_allclose(g, composite.TransformPoint(p), rtol=0, atol=1e-9)

    image = sitk.ReadImage(str(fixed))
    bspline = sitk.BSplineTransformInitializer(image, [2, 2, 2], 3)
    deformable = tmp_path / "deformable.tfm"
    sitk.WriteTransform(sitk.CompositeTransform([euler, bspline]), str(deformable))
    refused = warpbench("points", "--fixed", fixed, "--moving", moving, "--initial", deformable, "--landmarks",
                        pairs, "--from", "fixed", "--in", targets, "--out", tmp_path / "never.csv", expect=2)
    assert "deformable.tfm" in refused.stderr and "--initial-field" in refused.stderr, refused.stderr
