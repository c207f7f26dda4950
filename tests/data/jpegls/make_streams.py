#!/usr/bin/env python3
"""Writes the small JPEG-LS test streams of tests/data/jpegls/ (see README.md there).

    data-cache/venv/bin/pip install pillow-jpls==1.3.2
    data-cache/venv/bin/python tests/data/jpegls/make_streams.py

Each synthetic image (fixed seed) is encoded with CharLS (pillow-jpls's `_pycharls.encode`), decoded
again by CharLS and by libjpeg (pylibjpeg-libjpeg, an independent JPEG-LS implementation), and
written as `<name>.jls` plus `<name>.src.pgm` (the source samples). For near-lossless streams the
two decoders must agree and stay within NEAR of the source; their decode is `<name>.dec.pgm`.
"""
from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

import numpy as np
from libjpeg import decode as libjpeg_decode
from pillow_jpls import _pycharls as charls

OUT = Path(__file__).resolve().parent


def pgm(path: Path, a: np.ndarray, maxval: int) -> None:
    h, w = a.shape
    body = a.astype(">u2").tobytes() if maxval > 255 else a.astype("u1").tobytes()
    path.write_bytes(f"P5\n{w} {h}\n{maxval}\n".encode() + body)


def encode(a: np.ndarray, bits: int, spiff: bool = False, **kw) -> bytes:
    fi = charls.FrameInfo()
    fi.height, fi.width = a.shape
    fi.component_count = 1
    fi.bits_per_sample = bits
    buf = a.astype("<u2").tobytes() if bits > 8 else a.astype("u1").tobytes()
    header = None
    if spiff:
        header = charls.SpiffHeader()
        header.profile_id = charls.SpiffProfileId.NotSpecified
        header.component_count = 1
        header.height, header.width = a.shape
        header.color_space = charls.SpiffColorSpace.Grayscale
        header.bits_per_sample = bits
        header.compression_type = charls.SpiffCompressionType.JpegLs
        header.resolution_units = charls.SpiffResolutionUnits.DotsPerInch
        header.vertical_resolution = 96
        header.horizontal_resolution = 96
    return bytes(charls.encode(buf, fi, header, **kw))


def charls_decode(data: bytes, shape, bits: int) -> np.ndarray:
    raw = bytes(charls.decode(data))
    dt = "<u2" if bits > 8 else "u1"
    return np.frombuffer(raw, dtype=dt).reshape(shape).astype(np.int64)


def images() -> list[tuple[str, np.ndarray, int, dict]]:
    rng = np.random.default_rng(20240514)
    out = []
    # 8-bit ramp with mild noise: regular mode, small k.
    y, x = np.mgrid[0:23, 0:37]
    ramp = np.clip(3 * x + 2 * y + rng.integers(-2, 3, (23, 37)), 0, 255)
    out.append(("ramp_p8_37x23", ramp, 8, {}))
    # 12-bit uniform noise: large k and escape codes.
    out.append(("noise_p12_32x32", rng.integers(0, 4096, (32, 32)), 12, {}))
    # 16-bit flat regions, steps and a ramp: run mode, long runs (RUNindex high), run interruptions
    # of both types, runs ending at the end of a line.
    flat = np.full((48, 64), 1000, dtype=np.int64)
    flat[10:20, 5:60] = 40000
    flat[25:30, :] = 65535
    flat[30:48, 32:] = np.arange(32)[None, :] * 17 + 5000
    flat[40, 3] = 0
    flat[44:46, 10:13] = 1001
    out.append(("flat_p16_64x48", flat, 16, {}))
    # Full-range 16-bit noise: modulo wrap of the prediction error.
    out.append(("noise_p16_16x16", rng.integers(0, 65536, (16, 16)), 16, {}))
    # 2-bit image (the smallest precision; MAXVAL < 128 thresholds).
    out.append(("tiny_p2_17x9", rng.integers(0, 4, (9, 17)) * (rng.random((9, 17)) < 0.4), 2, {}))
    # Width 1 (Rd = Rb, Ra = Rb at every sample), near-lossless.
    col = np.clip(np.cumsum(rng.integers(-5, 6, (40, 1)), axis=0) + 500, 0, 1023)
    out.append(("column_p10_1x40_near1", col, 10, {"near_lossless": 1}))
    # Near-lossless NEAR = 3: smooth 16-bit field with noise and flat patches; an 8-bit one.
    yy, xx = np.mgrid[0:64, 0:64]
    smooth = 20000 + 3000 * np.sin(xx / 7.0) * np.cos(yy / 9.0) + rng.normal(0, 20, (64, 64))
    smooth[5:15, 40:60] = 12345
    out.append(("mixed_p16_64x64_near3", np.clip(smooth, 0, 65535).astype(np.int64), 16, {"near_lossless": 3}))
    m8 = np.clip(128 + 60 * np.sin(xx[:30, :40] / 5.0) + rng.normal(0, 4, (30, 40)), 0, 255).astype(np.int64)
    m8[20:, :] = 77
    out.append(("mixed_p8_40x30_near3", m8, 8, {"near_lossless": 3}))
    # LSE preset parameters: T1/T2/T3 10/40/200, RESET 32, NEAR 2, and a SPIFF header (APP8). (A preset
    # MAXVAL below 2^P - 1 is left out: CharLS 2 and libjpeg 2.5.0 decode such streams differently.)
    p12 = np.clip(2000 + 900 * np.sin(xx[:40, :48] / 6.0) + rng.normal(0, 30, (40, 48)), 0, 4000).astype(np.int64)
    p12[:8, :] = 4000
    out.append(("preset_p12_48x40_near2", p12, 12,
                {"near_lossless": 2, "t1": 10, "t2": 40, "t3": 200, "reset": 32, "spiff": True}))
    # Lossless with presets as well (T1/T2/T3 3/9/30, RESET 255).
    out.append(("preset_p8_37x23", ramp, 8, {"t1": 3, "t2": 9, "t3": 30, "reset": 255}))
    return out


def main() -> int:
    total = 0
    for name, a, bits, kw in images():
        spiff = kw.pop("spiff", False)
        near = kw.get("near_lossless", 0)
        data = encode(a, bits, spiff=spiff, **kw)
        maxval = kw.get("maxval", (1 << bits) - 1)
        ours = charls_decode(data, a.shape, bits)
        theirs = np.asarray(libjpeg_decode(data)).astype(np.int64).reshape(a.shape)
        assert np.array_equal(ours, theirs), f"{name}: CharLS and libjpeg disagree"
        err = int(np.abs(theirs - a).max())
        assert err <= near, f"{name}: error {err} > NEAR {near}"
        (OUT / f"{name}.jls").write_bytes(data)
        pgm(OUT / f"{name}.src.pgm", a, maxval)
        files = [f"{name}.jls", f"{name}.src.pgm"]
        if near > 0:
            pgm(OUT / f"{name}.dec.pgm", theirs, maxval)
            files.append(f"{name}.dec.pgm")
        size = sum((OUT / f).stat().st_size for f in files)
        total += size
        print(f"{name:28} P={bits:2} NEAR={near} {a.shape[1]}x{a.shape[0]} {len(data):6} B  max error {err}")
    print(f"total {total} bytes")
    print("versions:", {n: metadata.version(n) for n in ["pillow-jpls", "pylibjpeg-libjpeg", "numpy"]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
