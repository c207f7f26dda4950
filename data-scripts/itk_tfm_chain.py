#!/usr/bin/env python3
"""ITK's text transform files (.tfm) of several transforms, as SimpleITK writes a composite, and 3D Slicer's inverse
B-spline class in a text file.

Writes into tests/data/itk/ (deterministic: a rerun writes the same bytes):

- tfm_composite.tfm: SimpleITK's WriteTransform of CompositeTransform([A, B]): an affine A with a centre, then a
  cubic B-spline B (BSplineTransform_double_3_3, 6 x 6 x 6 control points over an oblique 60 x 50 x 40 mm box,
  seeded coefficients of at most 2.5 mm), so the file's transform is T(x) = A(B(x)), the last member first;
- tfm_bspline.tfm: B alone;
- tfm_slicer_inverse.tfm: the composite's text with B's class renamed to 3D Slicer's
  InverseBSplineTransform_double_3_3, the class Slicer writes for a B-spline whose inverse flag is set
  (vtkITKTransformInverse.h: the parameters describe S and the transform meant is S^-1), so T(x) = A(B^-1(x));
- tfm_chain_reference.json: seeded points x (inside B's domain, and some outside it, where ITK's B-spline is the
  identity) with SimpleITK's TransformPoint of the composite and of B alone; and seeded points y a control spacing
  inside the domain with B(y) and A(y): at x = B(y) the Slicer file must give A(y).

Usage, from the repository root (any Python with SimpleITK 2.5.7 and numpy, e.g. the venv `.ci/run` makes):

    target/ci-python-venv/bin/python data-scripts/itk_tfm_chain.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import SimpleITK as sitk

SEED = 20261207
ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "itk"


def bspline() -> "sitk.BSplineTransform":
    """B over an oblique box: 6 control points per axis (3 mesh cells), seeded coefficients up to 2.5 mm."""
    angle = np.deg2rad(15.0)
    c, s = np.cos(angle), np.sin(angle)
    direction = (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    domain = sitk.Image([31, 26, 21], sitk.sitkFloat32)
    domain.SetSpacing((2.0, 2.0, 2.0))
    domain.SetOrigin((-28.0, -22.0, -15.0))
    domain.SetDirection(direction)
    b = sitk.BSplineTransformInitializer(domain, [3, 3, 3], 3)
    rng = np.random.default_rng(SEED)
    coefficients = rng.uniform(-2.5, 2.5, size=len(b.GetParameters()))
    b.SetParameters(tuple(float(v) for v in coefficients))
    return b


def main() -> None:
    a = sitk.AffineTransform(3)
    a.SetMatrix((1.02, -0.08, 0.01, 0.07, 0.97, -0.03, -0.02, 0.04, 1.05))
    a.SetTranslation((3.5, -2.25, 1.75))
    a.SetCenter((4.0, -3.0, 2.0))
    b = bspline()
    composite = sitk.CompositeTransform([a, b])
    sitk.WriteTransform(composite, str(OUT / "tfm_composite.tfm"))
    sitk.WriteTransform(b, str(OUT / "tfm_bspline.tfm"))
    text = (OUT / "tfm_composite.tfm").read_text()
    if text.count("Transform: BSplineTransform_double_3_3") != 1:
        raise SystemExit("expected one B-spline in the composite")
    slicer = text.replace("Transform: BSplineTransform_double_3_3", "Transform: InverseBSplineTransform_double_3_3")
    (OUT / "tfm_slicer_inverse.tfm").write_text(slicer)

    rng = np.random.default_rng(SEED + 1)
    # Points in B's domain (60 x 50 x 40 mm along its rotated axes from its origin), and beyond it, where ITK's
    # B-spline is the identity.
    angle = np.deg2rad(15.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1.0]])
    extent, origin = np.array([60.0, 50.0, 40.0]), np.array([-28.0, -22.0, -15.0])

    def points(lo: float, hi: float, n: int) -> np.ndarray:
        return origin + (rotation @ (rng.uniform(lo, hi, size=(n, 3)) * extent).T).T

    xs = np.concatenate([points(0.03, 0.97, 30), points(1.1, 1.5, 5), points(-0.5, -0.1, 5)])
    # A quarter of the domain inside: B is smooth there, with one preimage near each image.
    ys = points(0.25, 0.75, 20)
    reference = {
        "generator": f"data-scripts/itk_tfm_chain.py, {sitk.Version.VersionString()}",
        "seed": SEED,
        "forward": [
            {"x": list(map(float, x)), "composite": list(composite.TransformPoint(tuple(map(float, x)))),
             "bspline": list(b.TransformPoint(tuple(map(float, x))))}
            for x in xs
        ],
        "inverse": [
            {"y": list(map(float, y)), "b_of_y": list(b.TransformPoint(tuple(map(float, y)))),
             "a_of_y": list(a.TransformPoint(tuple(map(float, y))))}
            for y in ys
        ],
    }
    (OUT / "tfm_chain_reference.json").write_text(json.dumps(reference, indent=1) + "\n")


if __name__ == "__main__":
    main()
