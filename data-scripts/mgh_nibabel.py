#!/usr/bin/env python3
"""FreeSurfer MGH / MGZ fixtures written by nibabel, and what nibabel reads back from each: tests/data/mgh/.

Every volume is small, written by nibabel 5.4.2 (`nibabel.freesurfer.mghformat.MGHImage`) both as `.mgh` (raw) and as
`.mgz` (gzip), so that a transposed direction matrix, a swapped axis, a lost centre or a wrong byte order shows:

- oblique_{u8,i16,u16,i32,f32}: 5x4x3 on an oblique grid (rotated about all three axes) with unequal, non-unit voxel
  sizes (0.7, 1.3, 2.5 mm) and a centre away from the origin, one file per MGH sample type (UCHAR 0, SHORT 4,
  USHRT 10, INT 1, FLOAT 3); the values cover each type's range (i32 ones that float32 does not hold exactly);
- frames_f32: 5x4x3x2, two frames, on the oblique grid;
- conformed_lia_u8: 6x5x4 in FreeSurfer's conformed orientation (LIA, 1 mm, as `orig.mgz`) with a non-zero c_ras;
- with_tags.mgz: oblique_i16.mgh with FreeSurfer-style tags after nibabel's scan parameters (a TAG_CMDLINE and an
  unknown tag), gzip-compressed by the script; readers ignore them;
- no_ras_flag.mgh: oblique_u8.mgh with goodRASFlag set to 0 by the script (the geometry fields are left as they
  are). nibabel then assumes unit voxels, c_ras 0 and its default direction, which is LSP; FreeSurfer's mghRead
  assumes its CORONAL default, LIA (x_ras = (-1, 0, 0), y_ras = (0, 0, -1), z_ras = (0, 1, 0)). The reference records
  nibabel's affine; warpbench follows FreeSurfer there (docs/formats.md).

reference.json records, for each volume: its files, the goodRASFlag the file holds, nibabel's header fields (type
code, dims, delta, Mdc as stored (rows x_ras, y_ras, z_ras), Pxyz_c), nibabel's `affine` (RAS vox2ras, 0-based indices), the dtype,
the shape and the voxels, i fastest (Fortran order), frame after frame. Floats are Python's repr (round-trip exact).
The script checks that nibabel reads each `.mgz` to the same header and voxels as the `.mgh`. gzip stamps the time, so
a rerun's `.mgz` bytes differ; the `.mgh` bytes and the reference do not.

`--check FILE...` writes nothing: it prints, as JSON, what nibabel reads from each FILE (an MGH or MGZ, e.g. one
warpbench wrote): dtype, shape, affine (RAS), the goodRASFlag the file holds and the sha256 of the voxels as little-endian samples of
their dtype, i fastest (`numpy.asarray(x, '<dtype').tobytes(order='F')`, what `VoxelData::to_le_bytes` gives for
a volume warpbench wrote), and the voxels themselves when there are at most 4096.

Usage, from the repository root (a Python with nibabel 5.4.2 and numpy, e.g. the venv `.ci/run` makes):

    target/ci-python-venv/bin/python data-scripts/mgh_nibabel.py
    target/ci-python-venv/bin/python data-scripts/mgh_nibabel.py --check out.mgz
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import struct
import sys
from pathlib import Path

import nibabel as nib
import numpy as np
from fixture_grids import affine, rotation
from nibabel.freesurfer.mghformat import MGHImage

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "mgh"
SHAPE = (5, 4, 3)


def affine_of(linear: np.ndarray, c_ras, shape) -> np.ndarray:
    """The vox2ras whose centre voxel (shape / 2, as MGH defines it) is at c_ras."""
    return affine(linear, np.asarray(c_ras) - linear @ (np.asarray(shape[:3]) / 2.0))


OBLIQUE = affine_of(rotation(0.3, -0.2, 0.5) @ np.diag([0.7, 1.3, 2.5]), (-12.5, 30.25, 7.0), SHAPE)
# FreeSurfer's conformed orientation: columns x_ras = (-1, 0, 0), y_ras = (0, 0, -1), z_ras = (0, 1, 0).
LIA = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
CONFORMED_SHAPE = (6, 5, 4)
CONFORMED = affine_of(LIA, (1.5, -17.25, 20.0), CONFORMED_SHAPE)


def pattern(dtype, lo: float, hi: float, shape=SHAPE) -> np.ndarray:
    """An array of `dtype` and `shape` covering lo..hi, different at every voxel."""
    idx = np.indices(shape)
    weights = [37, 11, 101, 53][: len(shape)]
    t = (sum(w * i for w, i in zip(weights, idx)) % 211) / 210.0
    return (lo + t * (hi - lo)).round().astype(dtype)


def volumes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(20261207)
    i32 = pattern(np.int64, -2_000_000_000, 2_000_000_000).astype(np.int32)
    i32.flat[:4] = [16_777_217, -16_777_219, 2_147_483_647, -2_147_483_648]  # not exact in float32
    f32 = (rng.standard_normal(SHAPE) * 1000.0).astype(np.float32)
    f32.flat[:3] = [1e-30, -3.4e38, 0.1]
    frames = (rng.standard_normal(SHAPE + (2,)) * 100.0).astype(np.float32)
    return {
        "oblique_u8": (pattern(np.uint8, 0, 255), OBLIQUE),
        "oblique_i16": (pattern(np.int16, -32768, 32767), OBLIQUE),
        "oblique_u16": (pattern(np.uint16, 0, 65535), OBLIQUE),
        "oblique_i32": (i32, OBLIQUE),
        "oblique_f32": (f32, OBLIQUE),
        "frames_f32": (frames, OBLIQUE),
        "conformed_lia_u8": (pattern(np.uint8, 0, 255, CONFORMED_SHAPE), CONFORMED),
    }


def flag_in_file(path: Path) -> int:
    """The goodRASFlag the file holds (nibabel's header sets 1 when it assumes its default for 0)."""
    opener = gzip.open if path.suffix.lower() == ".mgz" else open
    with opener(path, "rb") as f:
        return struct.unpack(">h", f.read(30)[28:30])[0]


def describe(path: Path) -> dict:
    img = nib.load(str(path))
    h = img.header
    data = np.asanyarray(img.dataobj)
    return {
        "type": int(h["type"]),
        "dims": [int(x) for x in h["dims"]],
        "good_ras_flag": flag_in_file(path),
        "delta": [float(x) for x in h["delta"]],
        "mdc_rows": [[float(x) for x in row] for row in h["Mdc"]],
        "c_ras": [float(x) for x in h["Pxyz_c"]],
        "affine": np.asarray(img.affine, dtype=np.float64).tolist(),
        "dtype": data.dtype.newbyteorder("=").name,
        "shape": list(data.shape),
        "voxels": [x.item() for x in data.flatten(order="F")],
    }


def tags() -> bytes:
    """FreeSurfer tags (`TAGwrite`: int32 tag, int64 length, then the bytes; all big-endian): a command line
    (TAG_CMDLINE, 3) and a tag no reader knows."""
    cmd = b"mri_convert in.nii out.mgz"
    return struct.pack(">iq", 3, len(cmd)) + cmd + struct.pack(">iq", 99, 4) + b"\x00\x01\x02\x03"


def make() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    reference: dict = {"reader": f"nibabel {nib.__version__}", "volumes": []}
    for name, (data, affine) in volumes().items():
        files = [f"{name}.mgh", f"{name}.mgz"]
        for f in files:
            nib.save(MGHImage(data, affine), str(OUT / f))
        seen = [describe(OUT / f) for f in files]
        assert seen[0] == seen[1], f"{name}: nibabel reads the .mgz differently from the .mgh"
        reference["volumes"].append({"name": name, "files": files, **seen[0]})

    raw = (OUT / "oblique_i16.mgh").read_bytes()
    with gzip.open(OUT / "with_tags.mgz", "wb") as f:
        f.write(raw + tags())
    seen = describe(OUT / "with_tags.mgz")
    assert seen == describe(OUT / "oblique_i16.mgh"), "tags change what nibabel reads"
    reference["volumes"].append({"name": "with_tags", "files": ["with_tags.mgz"], **seen})

    raw = bytearray((OUT / "oblique_u8.mgh").read_bytes())
    raw[28:30] = struct.pack(">h", 0)
    (OUT / "no_ras_flag.mgh").write_bytes(bytes(raw))
    reference["volumes"].append({"name": "no_ras_flag", "files": ["no_ras_flag.mgh"], **describe(OUT / "no_ras_flag.mgh")})

    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    for p in sorted(OUT.iterdir()):
        print(f"{p.name}: {p.stat().st_size} bytes")


def check(paths: list[str]) -> None:
    out = []
    for p in paths:
        img = nib.load(p)
        data = np.asanyarray(img.dataobj)
        le = data.astype(data.dtype.newbyteorder("<"), copy=False)
        entry = {
            "file": p,
            "dtype": data.dtype.newbyteorder("=").name,
            "shape": list(data.shape),
            "affine": np.asarray(img.affine, dtype=np.float64).tolist(),
            "good_ras_flag": flag_in_file(Path(p)),
            "sha256": hashlib.sha256(le.tobytes(order="F")).hexdigest(),
        }
        if data.size <= 4096:
            entry["voxels"] = [x.item() for x in data.flatten(order="F")]
        out.append(entry)
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", nargs="+", metavar="FILE", help="print what nibabel reads from each FILE; write nothing")
    args = ap.parse_args()
    if args.check:
        check(args.check)
    else:
        make()


if __name__ == "__main__":
    main()
