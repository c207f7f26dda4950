#!/usr/bin/env python3
"""A displacement field written by elastix's transformix, and where transformix maps the field's voxel centres:
tests/data/metaimage/transformix_field.{mhd,raw,mha} and transformix_field_reference.json.

transformix's `-def all` (here `itk.transformix_deformation_field`, itk-elastix 0.25.4 on ITK 5.4.7) writes the
deformation field D(x) = T(x) − x at every voxel centre x of the output grid its parameter map names (the pull-back:
the output point x reads the input at x + D(x)), as a MetaImage vector image. The transform is a cubic
`BSplineTransform` with seeded random coefficients (σ 1.5 mm) on a 6 mm control grid, over an oblique 9×8×7 output
grid (rotated 20° about S and 10° about L, anisotropic spacing, non-zero origin), so that a transposed direction, a
swapped component or a lost origin shows.

Files:

- transformix_field.mhd + transformix_field.raw: the field as transformix writes `deformationField.mhd` (ITK's
  MetaImage writer, uncompressed, MET_FLOAT, ElementNumberOfChannels = 3);
- transformix_field.mha: the same field in one zlib-compressed file;
- ../elastix/bspline_oblique.txt: the transform parameter file transformix read (written by ITK's
  `ParameterObject.WriteParameterFile`);
- transformix_field_reference.json: the grid (size, spacing, origin, direction as ITK reports them), and for every
  other voxel along each axis (80, i fastest) its centre x, LPS mm, and T(x) as transformix's point transformation (`outputpoints.txt`, its
  `OutputPoint`) gives it: an independent path through elastix from the field's.

Deterministic: a rerun writes the same bytes. Run from the repository root, with itk-elastix==0.25.4 installed:

    python3 data-scripts/elastix_field.py
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import itk
import numpy as np
from elastix_transforms import transformix_points_through

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "metaimage"
SIZE = (9, 8, 7)
SPACING = (1.5, 2.0, 2.5)
ORIGIN = (-10.5, 20.25, 3.0)
GRID_SPACING_MM = 6.0
GRID_SIZE = (7, 7, 7)
SIGMA_MM = 1.5


def rotation(axis: str, angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    if axis == "z":
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


DIRECTION = rotation("z", 20.0) @ rotation("x", 10.0)


def words(values) -> list[str]:
    return [repr(float(v)) for v in values]


def parameter_object() -> itk.ParameterObject:
    """A cubic B-spline transform over the output grid: its control grid starts one control spacing before the grid's
    first voxel (along the grid's own axes) and covers it; coefficients from a seeded generator."""
    extent = [(n - 1) * s for n, s in zip(SIZE, SPACING)]
    assert all(GRID_SPACING_MM * (g - 3) >= e for g, e in zip(GRID_SIZE, extent)), "the control grid covers the box"
    grid_origin = np.array(ORIGIN) - DIRECTION @ np.full(3, GRID_SPACING_MM)
    rng = np.random.default_rng(20261205)
    coefficients = rng.standard_normal(3 * int(np.prod(GRID_SIZE))) * SIGMA_MM
    m = {
        "Transform": ["BSplineTransform"],
        "NumberOfParameters": [str(coefficients.size)],
        "TransformParameters": words(coefficients),
        "InitialTransformParameterFileName": ["NoInitialTransform"],
        "HowToCombineTransforms": ["Compose"],
        "FixedImageDimension": ["3"],
        "MovingImageDimension": ["3"],
        "FixedInternalImagePixelType": ["float"],
        "MovingInternalImagePixelType": ["float"],
        "Size": [str(n) for n in SIZE],
        "Index": ["0", "0", "0"],
        "Spacing": words(SPACING),
        "Origin": words(ORIGIN),
        "Direction": words(DIRECTION.flatten(order="F")),
        "UseDirectionCosines": ["true"],
        "GridSize": [str(g) for g in GRID_SIZE],
        "GridIndex": ["0", "0", "0"],
        "GridSpacing": words([GRID_SPACING_MM] * 3),
        "GridOrigin": words(grid_origin),
        "GridDirection": words(DIRECTION.flatten(order="F")),
        "BSplineTransformSplineOrder": ["3"],
        "UseCyclicTransform": ["false"],
        "ResampleInterpolator": ["FinalBSplineInterpolator"],
        "FinalBSplineInterpolationOrder": ["3"],
        "Resampler": ["DefaultResampler"],
        "DefaultPixelValue": ["0"],
        "ResultImageFormat": ["mhd"],
        "ResultImagePixelType": ["float"],
        "CompressResultImage": ["false"],
    }
    po = itk.ParameterObject.New()
    po.AddParameterMap(m)
    return po


def grid_image() -> itk.Image:
    image = itk.image_from_array(np.zeros(SIZE[::-1], dtype=np.float32))
    image.SetSpacing(SPACING)
    image.SetOrigin(ORIGIN)
    image.SetDirection(itk.matrix_from_array(DIRECTION))
    return image


def main() -> None:
    po = parameter_object()
    image = grid_image()
    with tempfile.TemporaryDirectory() as tmp_name:
        # transformix also writes its deformationField.mhd into its output directory: keep that out of the checkout.
        field = itk.transformix_deformation_field(image, po, output_directory=tmp_name)
    OUT.mkdir(parents=True, exist_ok=True)
    itk.imwrite(field, str(OUT / "transformix_field.mhd"), compression=False)
    itk.imwrite(field, str(OUT / "transformix_field.mha"), compression=True)
    itk.ParameterObject.WriteParameterFile(po.GetParameterMap(0), str(ROOT / "tests" / "data" / "elastix" /
                                                                      "bspline_oblique.txt"))

    # Every other voxel along each axis (corners included): 5 × 4 × 4 of them.
    indices = [[i, j, k] for k in range(0, SIZE[2], 2) for j in range(0, SIZE[1], 2) for i in range(0, SIZE[0], 2)]
    centres = [list(image.TransformIndexToPhysicalPoint(ijk)) for ijk in indices]
    mapped = transformix_points_through(po, centres, image)
    read = itk.array_from_image(itk.imread(str(OUT / "transformix_field.mhd")))  # (k, j, i, c)
    worst = max(
        abs(c[a] + float(read[k, j, i, a]) - m[a]) for (i, j, k), c, m in zip(indices, centres, mapped) for a in range(3)
    )
    largest = float(np.linalg.norm(read, axis=-1).max())
    print(f"transformix: field vs its point transformation at {len(indices)} voxel centres: {worst:.3g} mm; "
          f"largest |D| {largest:.2f} mm")
    assert worst < 1e-4, worst
    doc = {
        "made_by": "data-scripts/elastix_field.py",
        "itk": itk.Version.GetITKVersion(),
        "itk_elastix": "0.25.4",
        "size": list(SIZE),
        "spacing": list(SPACING),
        "origin": list(ORIGIN),
        "direction": [float(v) for v in DIRECTION.flatten()],
        "indices": indices,
        "centres_lps": centres,
        "transformix_points_lps": mapped,
    }
    (OUT / "transformix_field_reference.json").write_text(json.dumps(doc) + "\n")


if __name__ == "__main__":
    main()
