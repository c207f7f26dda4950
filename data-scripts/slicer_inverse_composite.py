#!/usr/bin/env python3
"""A composite transform as 3D Slicer saves one whose non-linear members it holds in their modeling direction.

Writes into tests/data/itk/:
- h5_composite_slicer_inverse.h5: ITK's CompositeTransform_double_3_3 of three members, in the file's order: an
  affine A, a cubic B-spline B (BSplineTransform_double_3_3, 5 x 5 x 5 control points over the box of F's grid) and
  a displacement field F (DisplacementFieldTransform_double_3_3 on an oblique 8 x 7 x 6 grid of 4 mm, smooth
  displacements of at most 0.9 mm, so that it folds nowhere and has one inverse), written by ITK's
  TransformFileWriter; then the classes of B and F renamed to 3D Slicer's
  InverseBSplineTransform_double_3_3 and InverseDisplacementFieldTransform_double_3_3 (h5py, as the variable-length
  ASCII string ITK writes). Slicer writes those classes for a member whose inverse flag is set
  (vtkITKTransformConverter, vtkITKTransformInverse.h: storage only, the transform meant is the inverse of the one
  the parameters describe), so the file's transform is T(x) = A(B^-1(F^-1(x))), fixed -> moving as ITK maps points.
- h5_composite_slicer_inverse.json: seeded points y; ITK's TransformPoint of the plain composite F(B(y)) (x, where
  the file's transform must take y's image) and of A at y. T(x) = A(y) is the law a reader must meet.

The points y, B(y) and F(B(y)) all lie a voxel or more inside the field's grid (so inside the B-spline's domain): a
field is the identity outside its grid, so near its edge a point may have two preimages, and only inside is the
inverse the one meant. Run from the repository root (the values are
deterministic, but HDF5 stamps the objects it writes with the time, so a rerun's .h5 bytes differ):

    data-cache/venv/bin/python data-scripts/slicer_inverse_composite.py

It installs the pinned wheels as data-scripts/slicer_transforms.py does (itk-core, -numerics, -filtering, -io 5.4.7
and h5py 3.14.0) when an import fails.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from slicer_transforms import imports

SEED = 20261207
N_POINTS = 40
BSPLINE_CLASS = "BSplineTransform_double_3_3"
FIELD_CLASS = "DisplacementFieldTransform_double_3_3"
ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "itk"


def rename_member(h5py, path: Path, group: int, old_class: str, new_class: str) -> None:
    with h5py.File(path, "r+") as f:
        at = f"/TransformGroup/{group}/TransformType"
        dataset = f[at]
        old = [s.decode() if isinstance(s, bytes) else s for s in dataset[()]]
        if old != [old_class]:
            sys.exit(f"{path}: expected {at} [{old_class!r}], found {old!r}")
        dtype = dataset.dtype
        del f[at]
        f[f"/TransformGroup/{group}"].create_dataset("TransformType", data=[new_class.encode()], dtype=dtype)


def main() -> None:
    itk, h5py = imports()
    import numpy as np  # noqa: PLC0415

    rng = np.random.default_rng(SEED)
    size, spacing, origin = np.array([8, 7, 6]), np.array([4.0, 4.0, 4.0]), np.array([-14.0, -12.0, -10.0])
    c, s = np.cos(np.deg2rad(8.0)), np.sin(np.deg2rad(8.0))
    axes = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    k, j, i = np.meshgrid(*(np.arange(n) for n in size[::-1]), indexing="ij")
    p = origin + (np.stack([i, j, k], axis=-1) * spacing) @ axes.T
    vectors = np.stack(
        [0.9 * np.sin(p[..., 1] / 9.0), 0.7 * np.cos(p[..., 2] / 8.0), 0.6 * np.sin(p[..., 0] / 10.0)], axis=-1
    )
    grid = itk.image_from_array(np.ascontiguousarray(vectors), is_vector=True)
    grid.SetOrigin(origin.tolist())
    grid.SetSpacing(spacing.tolist())
    grid.SetDirection(itk.matrix_from_array(axes))
    field = itk.DisplacementFieldTransform[itk.D, 3].New()
    field.SetDisplacementField(grid)

    affine = itk.AffineTransform[itk.D, 3].New()
    c, s = np.cos(np.deg2rad(5.0)), np.sin(np.deg2rad(5.0))
    matrix = np.array([[c, -s, 0.02], [s, c, 0.0], [-0.01, 0.0, 1.03]])
    affine.SetMatrix(itk.matrix_from_array(matrix))
    affine.SetTranslation([2.5, -1.25, 0.75])

    bspline = itk.BSplineTransform[itk.D, 3, 3].New()
    bspline.SetTransformDomainOrigin(grid.GetOrigin())
    bspline.SetTransformDomainPhysicalDimensions(itk.Vector[itk.D, 3]((spacing * (size - 1)).tolist()))
    bspline.SetTransformDomainMeshSize([2, 2, 2])
    bspline.SetTransformDomainDirection(grid.GetDirection())
    n = bspline.GetNumberOfParameters()
    coefficients = rng.uniform(-0.8, 0.8, n)
    parameters = itk.OptimizerParameters[itk.D](n)
    for i, v in enumerate(coefficients):
        parameters[i] = float(v)
    bspline.SetParametersByValue(parameters)

    composite = itk.CompositeTransform[itk.D, 3].New()
    for member in (affine, bspline, field):
        composite.AddTransform(member)
    path = OUT / "h5_composite_slicer_inverse.h5"
    itk.transformwrite([composite], str(path))
    rename_member(h5py, path, 2, BSPLINE_CLASS, "Inverse" + BSPLINE_CLASS)
    rename_member(h5py, path, 3, FIELD_CLASS, "Inverse" + FIELD_CLASS)

    # x = F(B(y)): the plain chain [F, B] applied to y; y, B(y) and x a voxel or more inside the field's grid.
    plain = itk.CompositeTransform[itk.D, 3].New()
    plain.AddTransform(field)
    plain.AddTransform(bspline)

    def inside(p) -> bool:
        ijk = np.linalg.solve(axes, np.array(p) - origin) / spacing
        return bool(np.all(ijk >= 1.0) and np.all(ijk <= size - 2.0))

    ys, xs = [], []
    while len(ys) < N_POINTS:
        y = origin + ((1.0 + rng.uniform(0.0, 1.0, 3) * (size - 3.0)) * spacing) @ axes.T
        b = list(bspline.TransformPoint([float(v) for v in y]))
        x = list(plain.TransformPoint([float(v) for v in y]))
        if inside(y) and inside(b) and inside(x):
            ys.append(y)
            xs.append(x)
    ys = np.array(ys)
    a_of_y = [list(affine.TransformPoint([float(v) for v in y])) for y in ys]
    moved = max(float(np.linalg.norm(np.array(x) - y)) for x, y in zip(xs, ys))
    if moved < 0.5:
        sys.exit(f"the plain chain moves the points by at most {moved} mm; expected more")
    doc = {
        "generator": "data-scripts/slicer_inverse_composite.py",
        "itk_version": itk.Version.GetITKVersion(),
        "h5py_version": h5py.__version__,
        "seed": SEED,
        "note": "y: points; x: ITK's TransformPoint of the chain F(B(y)) (the B-spline and field of the file before "
        "their classes were renamed); a_of_y: ITK's TransformPoint of the file's affine at y. The file's transform "
        "A(B^-1(F^-1(x))) must give a_of_y at x.",
        "y": ys.tolist(),
        "x": xs,
        "a_of_y": a_of_y,
    }
    (OUT / "h5_composite_slicer_inverse.json").write_text(json.dumps(doc, separators=(",", ":")) + "\n")
    print(f"wrote {path.name} and h5_composite_slicer_inverse.json into {OUT}")


if __name__ == "__main__":
    main()
