#!/usr/bin/env python3
"""MetaImage fixtures written by SimpleITK, and what SimpleITK reads back from each: tests/data/metaimage/.

Every fixture is a small volume (7x6x5, or 3x2x2x2 for the 4-D one) on an oblique grid (rotated 20 deg about S and
10 deg about L), with a non-zero origin and anisotropic spacing, so that a transposed direction, a swapped axis or a
lost origin shows:

- oblique_i16.mha: int16 (MET_SHORT), zlib-compressed (CompressedData = True), values spanning -32768..32767;
- oblique_u8.mhd + oblique_u8.raw: uint8 (MET_UCHAR), uncompressed, detached data file;
- oblique_f32.mha: float32 (MET_FLOAT), uncompressed;
- oblique_f64.mha: float64 (MET_DOUBLE), compressed; values that float32 does not hold exactly;
- oblique_i8.mha: int8 (MET_CHAR), uncompressed;
- msb_u16.mha: uint16 (MET_USHORT) with BinaryDataByteOrderMSB = True: SimpleITK writes little-endian only, so
  this one is made by hand from SimpleITK's uncompressed file (header flag flipped, samples byte-swapped) and
  SimpleITK reads it back to the same values;
- frames_4d.mha: a 4-D 3x2x2x2 float32 image (two frames along the 4th axis, whose direction does not mix
  with the spatial ones).

sitk_reference.json records, for each file, what SimpleITK 2.5.7 (ITK 5.4) reports on reading it: pixel type,
size, origin, spacing, direction (row-major, as GetDirection returns it), lps_from_index = [D diag(s) | o] (4x4,
row-major) and the voxels, i fastest (Fortran order; numpy's array is k-j-i). Floats are written with Python's
repr (round-trip exact). Deterministic: a rerun writes the same bytes.

Usage, from the repository root:

    data-cache/venv/bin/python data-scripts/metaimage_sitk.py
"""

import json
import math
import os

import numpy as np
import SimpleITK as sitk

OUT = "tests/data/metaimage"


def rotation(axis, angle_deg):
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    if axis == "z":
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


DIRECTION = rotation("z", 20.0) @ rotation("x", 10.0)
SPACING = (0.7, 1.3, 2.5)
ORIGIN = (-10.5, 20.25, 3.0)


def image_of(array_kji, pixel_id=None):
    img = sitk.GetImageFromArray(array_kji)
    if pixel_id is not None:
        img = sitk.Cast(img, pixel_id)
    img.SetSpacing(SPACING)
    img.SetOrigin(ORIGIN)
    img.SetDirection(tuple(DIRECTION.flatten()))
    return img


def pattern(dtype, lo, hi):
    """A 5x6x7 (k, j, i) array of `dtype` covering lo..hi, different at every voxel."""
    k, j, i = np.meshgrid(np.arange(5), np.arange(6), np.arange(7), indexing="ij")
    t = ((i * 37 + j * 11 + k * 101) % 210) / 209.0
    return (lo + t * (hi - lo)).round().astype(dtype)


def describe(path, img):
    n = img.GetDimension()
    d = np.array(img.GetDirection()).reshape(n, n)
    s = np.array(img.GetSpacing())
    o = np.array(img.GetOrigin())
    lps_from_index = np.eye(4)
    lps_from_index[:3, :3] = d[:3, :3] @ np.diag(s[:3])
    lps_from_index[:3, 3] = o[:3]
    arr = sitk.GetArrayFromImage(img)
    # numpy's array is (k, j, i) (or (t, k, j, i)): i fastest is C order of the reversed axes.
    voxels = [x.item() for x in np.transpose(arr).flatten(order="F")]
    return {
        "file": os.path.basename(path),
        "pixel_type": img.GetPixelIDTypeAsString(),
        "size": list(img.GetSize()),
        "origin": list(img.GetOrigin()),
        "spacing": list(img.GetSpacing()),
        "direction": list(img.GetDirection()),
        "lps_from_index": lps_from_index.tolist(),
        "voxels": voxels,
    }


def main():
    os.makedirs(OUT, exist_ok=True)
    out = lambda name: os.path.join(OUT, name)  # noqa: E731
    made = []

    i16 = pattern(np.int16, -32768, 32767)
    sitk.WriteImage(image_of(i16), out("oblique_i16.mha"), True)
    made.append("oblique_i16.mha")

    sitk.WriteImage(image_of(pattern(np.uint8, 0, 255)), out("oblique_u8.mhd"), False)
    made.append("oblique_u8.mhd")

    rng = np.random.default_rng(20261205)
    f32 = (rng.standard_normal((5, 6, 7)) * 1000.0).astype(np.float32)
    sitk.WriteImage(image_of(f32), out("oblique_f32.mha"), False)
    made.append("oblique_f32.mha")

    f64 = rng.standard_normal((5, 6, 7)) * 1e3 + 1e-9
    sitk.WriteImage(image_of(f64), out("oblique_f64.mha"), True)
    made.append("oblique_f64.mha")

    sitk.WriteImage(image_of(pattern(np.int8, -128, 127)), out("oblique_i8.mha"), False)
    made.append("oblique_i8.mha")

    # Big-endian by hand: SimpleITK's uncompressed little-endian file, flag flipped and samples swapped.
    u16 = pattern(np.uint16, 0, 65535)
    tmp = out("msb_u16.tmp.mha")
    sitk.WriteImage(image_of(u16), tmp, False)
    raw = open(tmp, "rb").read()
    os.remove(tmp)
    end = raw.index(b"ElementDataFile = LOCAL\n") + len(b"ElementDataFile = LOCAL\n")
    header = raw[:end].replace(b"BinaryDataByteOrderMSB = False", b"BinaryDataByteOrderMSB = True")
    data = np.frombuffer(raw[end:], dtype="<u2").astype(">u2").tobytes()
    with open(out("msb_u16.mha"), "wb") as f:
        f.write(header + data)
    made.append("msb_u16.mha")

    # 4-D: two frames of a 3x2x2 float32 volume; the 4th axis is a plain frame axis.
    frames = np.arange(2 * 2 * 2 * 3, dtype=np.float32).reshape(2, 2, 2, 3) * 0.5 - 3.0
    img4 = sitk.GetImageFromArray(frames, isVector=False)
    img4.SetSpacing(SPACING + (1.0,))
    img4.SetOrigin(ORIGIN + (0.0,))
    d4 = np.eye(4)
    d4[:3, :3] = DIRECTION
    img4.SetDirection(tuple(d4.flatten()))
    sitk.WriteImage(img4, out("frames_4d.mha"), False)
    made.append("frames_4d.mha")

    reference = {
        "reader": f"SimpleITK {sitk.Version.VersionString()} (ITK {sitk.Version.ITKVersionString()})",
        "fixtures": [describe(out(name), sitk.ReadImage(out(name))) for name in made],
    }
    with open(out("sitk_reference.json"), "w") as f:
        json.dump(reference, f, indent=1)
        f.write("\n")
    for name in sorted(os.listdir(OUT)):
        print(f"{name}: {os.path.getsize(out(name))} bytes")


if __name__ == "__main__":
    main()
