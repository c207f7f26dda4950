#!/usr/bin/env python3
"""ITK HDF5 transform fixtures (`.h5`), and what SimpleITK makes of each: tests/data/itk/h5_*.

- h5_affine.h5: one AffineTransform (an oblique matrix, a translation and a non-zero centre);
- h5_field.h5: one DisplacementFieldTransform on a small oblique grid (6 x 5 x 4 voxels, seeded random vectors);
- h5_composite.h5: a CompositeTransform of an affine and a displacement field, as antsRegistration's
  `Composite.h5` holds them (ITK applies the last one first: x -> affine(x + D(x)));
- h5_linear_composite.h5: a CompositeTransform of two affines.

All four are written by SimpleITK's WriteTransform (ITK's HDF5TransformIO). h5_reference.json records, for each file,
the classes SimpleITK reads (a composite's members in the file's order), TransformPoint at 40 points in and around
the field's grid, and, for the files with a field, SimpleITK's TransformToDisplacementField of the whole transform on
that field's grid (vectors in LPS mm, x fastest). Floats with Python's repr. The values are deterministic; the .h5
bytes are not quite (HDF5 stamps its objects with the time they were written).

Usage, from the repository root, with SimpleITK 2.5.7 (the venv .ci/run makes has it):

    target/ci-python-venv/bin/python data-scripts/itk_h5_sitk.py
"""

import json
import os

import numpy as np
import SimpleITK as sitk

OUT = "tests/data/itk"


def affine(angle, scale, translation, centre):
    rot = sitk.VersorRigid3DTransform()
    rot.SetRotation((0.2, 0.3, 1.0), angle)
    m = np.array(rot.GetMatrix()).reshape(3, 3) @ np.diag(scale)
    m[0, 1] += 0.02
    a = sitk.AffineTransform(3)
    a.SetMatrix(tuple(m.flatten()))
    a.SetTranslation(translation)
    a.SetCenter(centre)
    return a


def field(rng):
    size = [6, 5, 4]
    rot = sitk.VersorRigid3DTransform()
    rot.SetRotation((1.0, -0.5, 0.25), 0.4)
    vectors = rng.normal(scale=2.5, size=(size[2], size[1], size[0], 3))
    image = sitk.GetImageFromArray(vectors, isVector=True)
    image.SetOrigin((-12.0, 8.5, -20.0))
    image.SetSpacing((4.0, 5.0, 6.5))
    image.SetDirection(rot.GetMatrix())
    return image


def main():
    rng = np.random.default_rng(20261206)
    out = lambda name: os.path.join(OUT, name)  # noqa: E731
    first = affine(0.3, (1.05, 0.97, 1.1), (3.25, -2.0 / 3.0, 1.5), (10.0, -20.0, 5.5))
    second = affine(-0.15, (0.98, 1.02, 1.0), (-4.0, 2.5, 0.75), (-3.0, 4.0, 12.0))
    grid = field(rng)
    displacement = sitk.DisplacementFieldTransform(sitk.Image(grid))

    written = {
        "h5_affine.h5": first,
        "h5_field.h5": displacement,
        "h5_composite.h5": sitk.CompositeTransform([first, sitk.DisplacementFieldTransform(sitk.Image(grid))]),
        "h5_linear_composite.h5": sitk.CompositeTransform([first, second]),
    }
    # Points in and around the field's grid: its corners span about 25 x 25 x 30 mm from the origin.
    low = np.array(grid.TransformContinuousIndexToPhysicalPoint((-2.0, -2.0, -2.0)))
    high = np.array(grid.TransformContinuousIndexToPhysicalPoint((7.0, 6.0, 5.0)))
    lo, hi = np.minimum(low, high), np.maximum(low, high)
    points = [list(map(float, p)) for p in rng.uniform(lo, hi, size=(40, 3))]

    cases = []
    for name, t in written.items():
        sitk.WriteTransform(t, out(name))
        back = sitk.ReadTransform(out(name))
        if back.GetName() == "CompositeTransform":
            back = sitk.CompositeTransform(back)
            classes = [back.GetNthTransform(i).GetName() for i in range(back.GetNumberOfTransforms())]
        else:
            classes = [back.GetName()]
        case = {
            "file": name,
            "classes": classes,
            "points": points,
            "transformed": [list(back.TransformPoint(p)) for p in points],
        }
        if name in ("h5_field.h5", "h5_composite.h5"):
            d = sitk.TransformToDisplacementField(
                back, sitk.sitkVectorFloat64, grid.GetSize(), grid.GetOrigin(), grid.GetSpacing(), grid.GetDirection()
            )
            case["grid"] = {
                "size": list(grid.GetSize()),
                "origin": list(grid.GetOrigin()),
                "spacing": list(grid.GetSpacing()),
                "direction": list(grid.GetDirection()),
            }
            case["displacements"] = sitk.GetArrayFromImage(d).reshape(-1, 3).tolist()
        cases.append(case)
    reference = {
        "reader": f"SimpleITK {sitk.Version.VersionString()} (ITK {sitk.Version.ITKVersionString()})",
        "cases": cases,
    }
    with open(out("h5_reference.json"), "w") as f:
        json.dump(reference, f, indent=1)
        f.write("\n")
    for c in cases:
        print(c["file"], c["classes"], "field" if "displacements" in c else "")


if __name__ == "__main__":
    main()
