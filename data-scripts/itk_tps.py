#!/usr/bin/env python3
"""ITK thin-plate-spline reference values for warpbench-solver's TPS cross-check.

Writes tests/data/itk/tps_reference.json: for a few seeded landmark sets (source p_i, target q_i) and
stiffness values λ, the outputs of ITK's ThinPlateSplineKernelTransform<double, 3> (kernel G(r) = r·I,
L = [K + λI, P; Pᵀ, 0], solved by vnl_svd) at seeded query points. The Rust test
crates/solver/tests/tps.rs fits `Tps::fit(source, target, stiffness)` and compares at every query point.

Run from the repository root (re-runnable, byte-for-byte deterministic output):

    data-cache/venv/bin/python data-scripts/itk_tps.py

It installs the pinned ITK wheel into data-cache/venv when `import itk` fails. Only `itk-core` is needed
(the transform lives in ITKCommon/ITKTransform); `pip install itk==5.4.7` pulls the same itk-core.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ITK_CORE_VERSION = "5.4.7"
SEED = 20260512
STIFFNESSES = [0.0, 0.5, 4.0]
N_QUERIES = 150
ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "itk" / "tps_reference.json"


def import_itk():
    try:
        import itk  # noqa: PLC0415
    except ImportError:
        subprocess.run([sys.executable, "-m", "pip", "install", f"itk-core=={ITK_CORE_VERSION}"], check=True)
        import itk  # noqa: PLC0415
    version = itk.Version.GetITKVersion()
    if version != ITK_CORE_VERSION:
        sys.exit(f"expected ITK {ITK_CORE_VERSION}, found {version}")
    return itk


def smooth_displacement(rng: np.random.Generator, p: np.ndarray) -> np.ndarray:
    """A small affine map plus three random sinusoids of ~6 mm amplitude and ~150 mm wavelength."""
    angle = np.deg2rad(3.0)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) * 1.02
    q = p @ rot.T + np.array([5.0, -3.0, 2.0])
    for _ in range(3):
        amp = rng.normal(0.0, 6.0, 3)
        omega = rng.normal(0.0, 1.0, 3)
        omega *= 2.0 * np.pi / 150.0 / np.linalg.norm(omega)
        phase = rng.uniform(0.0, 2.0 * np.pi)
        q = q + np.sin(p @ omega + phase)[:, None] * amp[None, :]
    return q


def queries(rng: np.random.Generator, source: np.ndarray) -> np.ndarray:
    """The landmarks themselves, points inside the 200 mm box, and points outside it (up to 250 mm)."""
    n_out = 30
    n_in = N_QUERIES - len(source) - n_out
    inside = rng.uniform(-100.0, 100.0, (n_in, 3))
    outside = rng.uniform(-250.0, 250.0, (4 * n_out, 3))
    outside = outside[np.abs(outside).max(axis=1) > 110.0][:n_out]
    return np.vstack([source, inside, outside])


def itk_spline(itk, source, target, stiffness=0.0):
    """ITK's ThinPlateSplineKernelTransform<double, 3> from `source` to `target`, its weights computed."""
    tps = itk.ThinPlateSplineKernelTransform[itk.D, 3].New()
    point_set_type = type(tps.GetSourceLandmarks())
    sets = []
    for pts in (source, target):
        ps = point_set_type.New()
        for i, p in enumerate(pts):
            ps.SetPoint(i, itk.Point[itk.D, 3]([float(v) for v in p]))
        sets.append(ps)
    tps.SetSourceLandmarks(sets[0])
    tps.SetTargetLandmarks(sets[1])
    tps.SetStiffness(stiffness)
    tps.ComputeWMatrix()
    return tps


def itk_map(itk, transform, points):
    """`transform`'s TransformPoint of each point, as lists of floats."""
    out = []
    for x in points:
        y = transform.TransformPoint(itk.Point[itk.D, 3]([float(v) for v in x]))
        out.append([float(y[0]), float(y[1]), float(y[2])])
    return out


def itk_outputs(itk, source, target, stiffness, query):
    return itk_map(itk, itk_spline(itk, source, target, stiffness), query)


def main() -> None:
    itk = import_itk()
    rng = np.random.default_rng(SEED)
    cases = []
    for name, n, kind in (("smooth12", 12, "smooth"), ("smooth50", 50, "smooth"), ("affine20", 20, "affine")):
        source = rng.uniform(-100.0, 100.0, (n, 3))
        if kind == "smooth":
            target = smooth_displacement(rng, source)
        else:
            a = np.eye(3) + rng.normal(0.0, 0.05, (3, 3))
            target = source @ a.T + rng.normal(0.0, 10.0, 3)
        query = queries(rng, source)
        results = [
            {"stiffness": lam, "outputs": itk_outputs(itk, source, target, lam, query)} for lam in STIFFNESSES
        ]
        cases.append(
            {
                "name": name,
                "source": source.tolist(),
                "target": target.tolist(),
                "queries": query.tolist(),
                "results": results,
            }
        )
    doc = {
        "generator": "data-scripts/itk_tps.py",
        "itk_version": itk.Version.GetITKVersion(),
        "transform": "itk.ThinPlateSplineKernelTransform[itk.D, 3]",
        "seed": SEED,
        "note": "the first len(source) queries of each case are the source landmarks themselves",
        "cases": cases,
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(doc, indent=None, separators=(",", ":")) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
