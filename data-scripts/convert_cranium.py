#!/usr/bin/env python3
"""Convert InVesalius' Cranium.inv3 (a gzip tar) into tests/data/nifti/cranium_ct.nii.gz.

The project holds `matrix.dat`: raw little-endian int16 HU, shape [108][256][256] = (z, y, x), and
`main.plist` with spacing (0.9570312, 0.9570312, 1.5). It has no DICOM position or orientation, so
the affine is ASSUMED (documented in tests/data/PROVENANCE.md):

  - x (i): index increases towards the patient's LEFT   (assumed; left/right cannot be told from the
           image: the usual DICOM axial storage, which InVesalius keeps for x)
  - y (j): index increases towards ANTERIOR             (seen: the face is at high y)
  - z (k): index increases towards SUPERIOR             (seen: the vertex is at high z)

  RAS affine = [[-0.9570312, 0, 0,  +122.0214780],
                [0, 0.9570312, 0,  -122.0214780],
                [0, 0, 1.5,         -80.25      ],
                [0, 0, 0, 1]]
  i.e. the centre of the volume is at (0, 0, 0). Stored as both qform and sform, code 1 (scanner).

The output is byte-for-byte reproducible (gzip mtime 0, no file name in the gzip header).

Usage: python convert_cranium.py CRANIUM_INV3 OUT_NII_GZ
"""

from __future__ import annotations

import gzip
import io
import plistlib
import sys
import tarfile

import nibabel as nib
import numpy as np

SHAPE_ZYX = (108, 256, 256)


def main(src: str, dst: str) -> int:
    with tarfile.open(src, "r:gz") as tar:
        members = {m.name.rsplit("/", 1)[-1]: m for m in tar.getmembers() if m.isfile()}
        plist = plistlib.loads(tar.extractfile(members["main.plist"]).read())
        raw = tar.extractfile(members["matrix.dat"]).read()
    m = plist["matrix"]
    assert m["dtype"] == "int16" and tuple(m["shape"]) == SHAPE_ZYX, m
    assert plist["modality"] == "CT", plist["modality"]
    sx, sy, sz = (float(v) for v in plist["spacing"])
    zyx = np.frombuffer(raw, dtype="<i2").reshape(SHAPE_ZYX)
    xyz = np.ascontiguousarray(zyx.transpose(2, 1, 0))  # [i=x, j=y, k=z]
    nx, ny, nz = xyz.shape
    aff = np.array([
        [-sx, 0.0, 0.0, sx * (nx - 1) / 2.0],
        [0.0, sy, 0.0, -sy * (ny - 1) / 2.0],
        [0.0, 0.0, sz, -sz * (nz - 1) / 2.0],
        [0.0, 0.0, 0.0, 1.0],
    ])
    hdr = nib.Nifti1Header()
    hdr.set_data_dtype(np.int16)
    img = nib.Nifti1Image(xyz, aff, hdr)
    img.set_qform(aff, code=1)
    img.set_sform(aff, code=1)
    img.header.set_xyzt_units("mm", "sec")
    img.header["descrip"] = b"InVesalius Cranium CT (HU); x=L assumed"
    img.header.set_slope_inter(1.0, 0.0)
    bio = io.BytesIO()
    file_map = nib.Nifti1Image.make_file_map({"image": bio, "header": bio})
    img.to_file_map(file_map, dtype=np.int16)
    data = gzip.compress(bio.getvalue(), compresslevel=9, mtime=0)
    with open(dst, "wb") as f:
        f.write(data)
    print(f"{dst}: {xyz.shape} int16 range {xyz.min()}..{xyz.max()}, {len(data)} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
