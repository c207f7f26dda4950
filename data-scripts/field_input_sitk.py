#!/usr/bin/env python3
"""An independent reference for `warpbench warp --field`: SimpleITK resamples a tiny volume through a tiny field.

Writes into tests/data/itk/ (all small; deterministic, a rerun writes the same bytes):

- field_input_moving.nii.gz: 16x16x16 float32, 2.5 mm, axis-aligned, a smooth pattern with a few blobs;
- field_input_fixed.nii.gz: 16x14x12 uint8 zeros, 2 mm, axis-aligned: only its grid is used (the output grid);
- field_input_field.nii.gz: a pull-back displacement field on an OBLIQUE 9x8x7 grid (3 mm, rotated 20 deg about
  S and 10 deg about L), smaller than the fixed grid so that part of the fixed grid lies outside it, written the
  way ITK >= 5.3, ANTs and Slicer read a NIfTI field: intent NIFTI_INTENT_DISPVECT (1006), dim [5, X, Y, Z, 1, 3],
  float32, vectors in RAS (nibabel writes the file; SimpleITK reads it back and the script checks that ITK's
  reading gives the intended LPS vectors);
- field_input_field_sitk.nii.gz: the same field as SimpleITK's own writer stores a vector image (intent
  NIFTI_INTENT_VECTOR 1007, vectors as ITK holds them, LPS), for readers of that flavour;
- field_input_reference.json: SimpleITK's Resample(moving, fixed, DisplacementFieldTransform(field), linear,
  default 0, float32) at every voxel of the fixed grid (i fastest), and TransformPoint at probe points inside, in
  the outer half voxel and outside the field's grid.

Usage, from the repository root (any Python with SimpleITK 2.5.7, nibabel and numpy):

    python data-scripts/field_input_sitk.py
"""

import gzip
import hashlib
import io
import json
import math
import os

import nibabel as nib
import numpy as np
import SimpleITK as sitk

OUT = "tests/data/itk"


def sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def rotation(axis, angle_deg):
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    if axis == "z":
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def write_gz_deterministic(path, nifti_image):
    """nibabel's gzip carries a timestamp; write the bytes through gzip with mtime 0 instead."""
    raw = nifti_image.to_bytes()
    buf = io.BytesIO()
    with gzip.GzipFile(fileobj=buf, mode="wb", mtime=0, compresslevel=9) as g:
        g.write(raw)
    with open(path, "wb") as f:
        f.write(buf.getvalue())


def ras_affine(lps_from_index):
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    return flip @ lps_from_index


def write_volume(path, data_xyz, lps_from_index):
    img = nib.Nifti1Image(data_xyz, ras_affine(lps_from_index))
    img.header.set_qform(ras_affine(lps_from_index), code=1)
    img.header.set_sform(ras_affine(lps_from_index), code=1)
    img.header.set_xyzt_units("mm")
    write_gz_deterministic(path, img)


def main():
    os.makedirs(OUT, exist_ok=True)
    # Moving: 16^3 float32, 2.5 mm, centred on the origin.
    n_m = 16
    sp_m = 2.5
    o_m = -0.5 * (n_m - 1) * sp_m
    moving_lps_from_index = np.eye(4)
    moving_lps_from_index[:3, :3] = np.diag([sp_m] * 3)
    moving_lps_from_index[:3, 3] = [o_m] * 3
    i, j, k = np.meshgrid(np.arange(n_m), np.arange(n_m), np.arange(n_m), indexing="ij")
    x, y, z = (o_m + sp_m * a for a in (i, j, k))
    moving = 100 + 40 * np.sin(x / 6.0) * np.cos(y / 7.0) + 30 * np.sin(z / 5.0 + 0.3)
    for c, r in [((-5, 4, 2), 4.0), ((6, -3, -6), 5.0), ((0, 8, -8), 3.0)]:
        moving += 200 * np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / (2 * r * r))
    moving = moving.astype(np.float32)
    write_volume(f"{OUT}/field_input_moving.nii.gz", moving, moving_lps_from_index)

    # Fixed (output grid): 16x14x12 uint8, 2 mm, centred on the origin.
    dims_f = (16, 14, 12)
    fixed_lps_from_index = np.eye(4)
    fixed_lps_from_index[:3, :3] = np.diag([2.0] * 3)
    fixed_lps_from_index[:3, 3] = [-0.5 * (n - 1) * 2.0 for n in dims_f]
    write_volume(f"{OUT}/field_input_fixed.nii.gz", np.zeros(dims_f, np.uint8), fixed_lps_from_index)

    # The field: an oblique 9x8x7 grid, 3 mm, centred at (1, -1, 2) mm LPS.
    dims_d = (9, 8, 7)
    direction = rotation("z", 20.0) @ rotation("x", 10.0)
    centre = np.array([1.0, -1.0, 2.0])
    linear = direction * 3.0
    origin = centre - linear @ (0.5 * (np.array(dims_d) - 1))
    field_lps_from_index = np.eye(4)
    field_lps_from_index[:3, :3] = linear
    field_lps_from_index[:3, 3] = origin
    ii, jj, kk = np.meshgrid(*(np.arange(n) for n in dims_d), indexing="ij")
    idx = np.stack([ii, jj, kk, np.ones_like(ii)], axis=-1).astype(float)
    p = idx @ field_lps_from_index.T  # LPS of every voxel centre, [X, Y, Z, 4]
    px, py, pz = p[..., 0], p[..., 1], p[..., 2]
    d_lps = np.stack(
        [
            2.5 * np.sin(py / 8.0 + 0.2) + 0.5,
            -2.0 * np.cos(px / 9.0) * np.sin(pz / 10.0),
            1.5 * np.sin((px + pz) / 7.0) - 0.75,
        ],
        axis=-1,
    ).astype(np.float32)

    # The ITK flavour: DISPVECT, RAS vectors, shape [X, Y, Z, 1, 3].
    d_ras = d_lps * np.array([-1.0, -1.0, 1.0], np.float32)
    img = nib.Nifti1Image(d_ras.reshape(dims_d + (1, 3)), ras_affine(field_lps_from_index))
    img.header.set_intent(1006)
    img.header.set_qform(ras_affine(field_lps_from_index), code=1)
    img.header.set_sform(ras_affine(field_lps_from_index), code=1)
    img.header.set_xyzt_units("mm")
    field_path = f"{OUT}/field_input_field.nii.gz"
    write_gz_deterministic(field_path, img)

    # What ITK reads: the field as SimpleITK holds it must be the LPS vectors built above.
    field_img = sitk.ReadImage(field_path)
    held = sitk.GetArrayFromImage(field_img)  # [Z, Y, X, 3]
    err = float(np.abs(held.transpose(2, 1, 0, 3) - d_lps).max())
    if err > 1e-6:
        raise SystemExit(f"SimpleITK reads the DISPVECT vectors differently (max diff {err})")
    geom_err = float(
        np.abs(np.array(field_img.TransformContinuousIndexToPhysicalPoint((1.0, 2.0, 3.0)))
               - (field_lps_from_index @ [1.0, 2.0, 3.0, 1.0])[:3]).max()
    )
    if geom_err > 1e-5:
        raise SystemExit(f"SimpleITK reads the field's geometry differently ({geom_err} mm)")
    sitk_path = f"{OUT}/field_input_field_sitk.nii.gz"
    sitk.WriteImage(sitk.Cast(field_img, sitk.sitkVectorFloat32), sitk_path, useCompression=True)

    transform = sitk.DisplacementFieldTransform(sitk.Cast(field_img, sitk.sitkVectorFloat64))
    moving_img = sitk.ReadImage(f"{OUT}/field_input_moving.nii.gz")
    fixed_img = sitk.ReadImage(f"{OUT}/field_input_fixed.nii.gz")
    out = sitk.Resample(moving_img, fixed_img, transform, sitk.sitkLinear, 0.0, sitk.sitkFloat32)
    values = sitk.GetArrayFromImage(out).transpose(2, 1, 0).flatten(order="F")  # i fastest
    # Voxels of the fixed grid outside the field's grid (zero displacement there).
    fx = sitk.GetArrayFromImage(out)
    inside_field = 0
    for kz in range(dims_f[2]):
        for jy in range(dims_f[1]):
            for ix in range(dims_f[0]):
                pt = fixed_img.TransformIndexToPhysicalPoint((ix, jy, kz))
                c = field_img.TransformPhysicalPointToContinuousIndex(pt)
                if all(-0.5 <= c[a] < dims_d[a] - 0.5 for a in range(3)):
                    inside_field += 1
    del fx

    probes = []
    for c in [(4.0, 3.5, 3.0), (0.2, 6.9, 1.3), (-0.4, 2.0, 2.0), (8.45, 7.45, 6.45), (-0.6, 2.0, 2.0),
              (4.0, 8.0, 3.0), (12.0, -3.0, 1.0)]:
        x = field_img.TransformContinuousIndexToPhysicalPoint(c)
        probes.append({"index": list(c), "x": list(x), "T(x)": list(transform.TransformPoint(x))})

    report = {
        "tool": f"SimpleITK {sitk.Version.VersionString()} (ITK {sitk.Version.ITKVersionString()})",
        "note": "LPS mm (ITK physical space); output values float32 as float, i fastest",
        "moving": {"file": "field_input_moving.nii.gz", "sha256": sha256(f"{OUT}/field_input_moving.nii.gz")},
        "fixed": {"file": "field_input_fixed.nii.gz", "sha256": sha256(f"{OUT}/field_input_fixed.nii.gz")},
        "field": {"file": "field_input_field.nii.gz", "sha256": sha256(field_path)},
        "field_sitk": {"file": "field_input_field_sitk.nii.gz", "sha256": sha256(sitk_path)},
        "resample": "sitk.Resample(moving, fixed, DisplacementFieldTransform(field), sitkLinear, 0.0, sitkFloat32)",
        "dims": list(dims_f),
        "fixed_voxels_inside_field": inside_field,
        "values": [float(v) for v in values],
        "probes": probes,
    }
    with open(f"{OUT}/field_input_reference.json", "w") as f:
        json.dump(report, f, separators=(",", ":"))
        f.write("\n")
    total = int(np.prod(dims_f))
    print(f"wrote {OUT}/field_input_*: {total} voxels, {inside_field} inside the field's grid")
    for name in ["moving", "fixed", "field", "field_sitk"]:
        print(name, report[name]["sha256"], os.path.getsize(f"{OUT}/{report[name]['file']}"), "bytes")


if __name__ == "__main__":
    main()
