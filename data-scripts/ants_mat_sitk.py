#!/usr/bin/env python3
"""ANTs / ITK affine `.mat` fixtures (MATLAB v4), and what SimpleITK reads from each: tests/data/itk/.

- affine_sitk.mat and affine_sitk.tfm: one AffineTransform (an oblique matrix, a translation and a non-zero centre)
  written by SimpleITK's WriteTransform to both names: ITK's MatlabTransformIO for .mat, its text writer for .tfm;
- affine_be.mat: affine_sitk.mat with every header word and value byte-swapped (MATLAB type code 1000: big-endian
  doubles), made here since ITK writes the machine's byte order;
- affine_float.mat: the variables as ITK writes a float transform (`AffineTransform_float_3_3`, MATLAB type code 10:
  little-endian float32 values), as antsRegistration's `*0GenericAffine.mat` holds them, made here.

ants_mat_reference.json records, for each .mat, SimpleITK's ReadTransform: the class, GetParameters (the matrix row
by row, then the translation), GetFixedParameters (the centre), and TransformPoint at three points. Floats with
Python's repr. Deterministic: a rerun writes the same bytes.

Usage, from the repository root:

    data-cache/venv/bin/python data-scripts/ants_mat_sitk.py
"""

import json
import os
import struct

import numpy as np
import SimpleITK as sitk

OUT = "tests/data/itk"
POINTS = [[0.0, 0.0, 0.0], [12.5, -30.0, 8.0], [-91.0, 126.0, -72.0]]


def variable(name, values, big_endian, precision):
    """One MATLAB v4 variable: a n x 1 column of doubles (precision 0) or floats (1)."""
    order = ">" if big_endian else "<"
    code = (1000 if big_endian else 0) + 10 * precision
    raw = name.encode() + b"\0"
    head = struct.pack(order + "5i", code, len(values), 1, 0, len(raw))
    fmt = order + ("d" if precision == 0 else "f") * len(values)
    return head + raw + struct.pack(fmt, *values)


def main():
    out = lambda name: os.path.join(OUT, name)  # noqa: E731
    a = sitk.AffineTransform(3)
    rot = sitk.VersorRigid3DTransform()
    rot.SetRotation((0.0, 0.0, 1.0), 0.3)
    m = np.array(rot.GetMatrix()).reshape(3, 3) @ np.diag([1.05, 0.97, 1.1])
    m[0, 1] += 0.02
    a.SetMatrix(tuple(m.flatten()))
    a.SetTranslation((3.25, -2.0 / 3.0, 1e-9))
    a.SetCenter((10.0, -20.0, 5.5))
    sitk.WriteTransform(a, out("affine_sitk.mat"))
    sitk.WriteTransform(a, out("affine_sitk.tfm"))

    params = list(a.GetParameters())
    centre = list(a.GetFixedParameters())
    with open(out("affine_be.mat"), "wb") as f:
        f.write(variable("AffineTransform_double_3_3", params, True, 0) + variable("fixed", centre, True, 0))
    with open(out("affine_float.mat"), "wb") as f:
        f.write(variable("AffineTransform_float_3_3", params, False, 1) + variable("fixed", centre, False, 1))

    cases = []
    for name in ["affine_sitk.mat", "affine_be.mat", "affine_float.mat"]:
        t = sitk.ReadTransform(out(name))
        cases.append({
            "file": name,
            "class": t.GetName(),
            "parameters": list(t.GetParameters()),
            "fixed_parameters": list(t.GetFixedParameters()),
            "points": POINTS,
            "transformed": [list(t.TransformPoint(p)) for p in POINTS],
        })
    reference = {
        "reader": f"SimpleITK {sitk.Version.VersionString()} (ITK {sitk.Version.ITKVersionString()})",
        "tfm": "affine_sitk.tfm",
        "cases": cases,
    }
    with open(out("ants_mat_reference.json"), "w") as f:
        json.dump(reference, f, indent=1)
        f.write("\n")
    for c in cases:
        print(c["file"], c["class"], c["parameters"][:3], c["fixed_parameters"])


if __name__ == "__main__":
    main()
