#!/usr/bin/env python3
"""ITK's linear transform classes besides the affine, as SimpleITK writes them, and where each maps points:
tests/data/itk/linear_*.tfm, h5_linear_classes.h5 and linear_reference.json.

One `.tfm` per class (ITK's text writer): TranslationTransform, ScaleTransform, Euler3DTransform (ZXY and, with
ComputeZYX, ZYX), VersorTransform, VersorRigid3DTransform, Similarity3DTransform, ScaleVersor3DTransform and
ScaleSkewVersor3DTransform (ITK 5's, 15 parameters), each with a non-zero centre where the class has one; and one `.h5`
(ITK's HDF5TransformIO) holding all nine in a CompositeTransform. These are what SimpleITK's registration examples
write (a CenteredTransformInitializer and an Euler3DTransform, say).
linear_reference.json records, for each file, SimpleITK's ReadTransform class and TransformPoint at 12 points. The
.tfm files and the values are deterministic; the .h5 bytes are not quite (HDF5 stamps its objects with the time).

Usage, from the repository root, with SimpleITK 2.5.7 (the venv .ci/run makes has it):

    target/ci-python-venv/bin/python data-scripts/itk_linear_sitk.py
"""

import json
import os

import numpy as np
import SimpleITK as sitk

OUT = "tests/data/itk"


def transforms():
    euler = sitk.Euler3DTransform((10.0, -20.0, 5.5), 0.1, -0.25, 0.4, (3.25, -2.0 / 3.0, 1.5))
    euler_zyx = sitk.Euler3DTransform((-4.0, 7.0, 12.0), -0.3, 0.15, 0.2, (-1.0, 2.5, -3.0))
    euler_zyx.SetComputeZYX(True)
    similarity = sitk.Similarity3DTransform(1.07, (0.3, -0.5, 1.0), 0.35, (4.0, -3.0, 2.0), (6.0, 8.0, -10.0))
    # ITK adds these scales (and skews) to the rotation matrix rather than multiplying it.
    scale_versor = sitk.ScaleVersor3DTransform()
    scale_versor.SetParameters((0.12, -0.2, 0.25, 1.5, -2.5, 3.0, 1.1, 0.92, 1.05))
    scale_versor.SetCenter((2.0, -6.0, 4.5))
    scale_skew_versor = sitk.ScaleSkewVersor3DTransform()
    scale_skew_versor.SetParameters((-0.1, 0.15, 0.3, -3.0, 1.0, 2.5, 0.95, 1.08, 1.12,
                                     0.04, -0.06, 0.09, 0.03, -0.02, 0.05))
    scale_skew_versor.SetCenter((-5.0, 1.5, 7.0))
    return {
        "linear_translation.tfm": sitk.TranslationTransform(3, (2.5, -1.25, 0.75)),
        "linear_scale.tfm": sitk.ScaleTransform(3, (1.1, 0.9, 1.25)),
        "linear_euler.tfm": euler,
        "linear_euler_zyx.tfm": euler_zyx,
        "linear_versor.tfm": sitk.VersorTransform((1.0, 0.2, -0.4), 0.5, (3.0, 1.0, -2.0)),
        "linear_versor_rigid.tfm": sitk.VersorRigid3DTransform((-0.2, 1.0, 0.3), -0.4, (2.0, -5.0, 1.0),
                                                                (1.5, 0.5, -2.5)),
        "linear_similarity.tfm": similarity,
        "linear_scale_versor.tfm": scale_versor,
        "linear_scale_skew_versor.tfm": scale_skew_versor,
    }


def main():
    rng = np.random.default_rng(20261206)
    out = lambda name: os.path.join(OUT, name)  # noqa: E731
    written = transforms()
    scale = written["linear_scale.tfm"]
    scale.SetCenter((-7.0, 3.0, 9.0))
    points = [list(map(float, p)) for p in rng.uniform(-120.0, 120.0, size=(12, 3))]
    cases = []
    for name, t in written.items():
        sitk.WriteTransform(t, out(name))
    composite = sitk.CompositeTransform(list(written.values()))
    sitk.WriteTransform(composite, out("h5_linear_classes.h5"))
    for name in [*written, "h5_linear_classes.h5"]:
        back = sitk.ReadTransform(out(name))
        cases.append({
            "file": name,
            "class": back.GetName(),
            "points": points,
            "transformed": [list(back.TransformPoint(p)) for p in points],
        })
    reference = {
        "reader": f"SimpleITK {sitk.Version.VersionString()} (ITK {sitk.Version.ITKVersionString()})",
        "cases": cases,
    }
    with open(out("linear_reference.json"), "w") as f:
        json.dump(reference, f, indent=1)
        f.write("\n")
    for c in cases:
        print(c["file"], c["class"])


if __name__ == "__main__":
    main()
