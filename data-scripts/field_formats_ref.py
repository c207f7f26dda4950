#!/usr/bin/env python3
"""Each displacement-field flavour of `warpbench field --format`, read by its tool's reader, for
crates/app/tests/field_formats_cli.rs.

On tests/data/nifti/avg152T1_LR_nifti.nii (fixed and moving) with the pairs tests/data/itk/field_pairs.csv (TPS), the
script has `warpbench field` write

- `--format itk` (NIfTI intent DISPVECT, RAS vectors), read by SimpleITK's `ReadImage` (ITK's NIfTI reader flips the
  vectors to LPS) and by nibabel (raw RAS vectors, intent code 1006);
- `--format ants` (NIfTI intent VECTOR, LPS vectors), read by nibabel (the raw array, as ANTs' documentation describes
  its warp files: a 5-D NIfTI whose 5th dimension holds the LPS displacement) and by SimpleITK (ITK reads intent 1007
  without any flip);
- `--format nrrd` (LPS vectors, `kinds: vector domain domain domain`), read by SimpleITK's NRRD reader;
- `--format itk --direction forward` (d(y) − y on the moving grid), read by SimpleITK;
- `--format metaimage` (a MetaImage vector image, LPS vectors, as transformix writes its deformation field), read by
  SimpleITK's MetaImage reader;

and compares every reading, at the voxel centres of a sub-grid (every 26th voxel along each axis: 80 voxels), with
warpbench's own maps at those points (`warpbench points --from fixed` for the pull-back u, `--from moving` for the
forward map d): |reading − (map(x) − x)| must stay below 1e-5 mm (float32 rounding). Each file is also applied as
ITK's `DisplacementFieldTransform` (SimpleITK's `TransformPoint`, linear interpolation of the field, as ANTs and
Slicer apply fields) at 12 off-grid points, which must land within 0.05 mm of warpbench's exact map (measured:
3e-3 mm, the interpolation error). It writes tests/data/itk/field_formats_reference.json: per flavour the header
facts each reader reported, SimpleITK's (and nibabel's) vectors at those voxels, and ITK's transformed off-grid
points, LPS mm. Deterministic: a rerun writes the same bytes.

Run from the repository root, with SimpleITK==2.5.7 and nibabel installed in the Python that runs it:

    python3 data-scripts/field_formats_ref.py target/debug/warpbench
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import nibabel as nib
import numpy as np
import SimpleITK as sitk

ROOT = Path(__file__).resolve().parent.parent
VOLUME = ROOT / "tests" / "data" / "nifti" / "avg152T1_LR_nifti.nii"
PAIRS = ROOT / "tests" / "data" / "itk" / "field_pairs.csv"
OUT = ROOT / "tests" / "data" / "itk" / "field_formats_reference.json"
STRIDE = 26
TOLERANCE_MM = 1e-5
# Off-grid continuous indices where ITK's DisplacementFieldTransform (the class ANTs and Slicer apply fields with)
# interpolates the field linearly; inside the grid, where ITK's interpolation is defined.
OFF_GRID = [[4.25 + 7.0 * n, 6.5 + 8.25 * n, 3.75 + 6.5 * n] for n in range(12)]
# Linear interpolation of the sampled field against the exact map, on this smooth TPS with 2 mm voxels.
INTERPOLATION_MM = 0.05
FLAVOURS = [
    ("itk", "field_itk.nii.gz", ["--format", "itk"]),
    ("ants", "field_ants.nii.gz", ["--format", "ants"]),
    ("nrrd", "field.nrrd", ["--format", "nrrd"]),
    ("itk_forward", "forward_itk.nii.gz", ["--format", "itk", "--direction", "forward"]),
    ("metaimage", "field.mha", ["--format", "metaimage"]),
]


def run(exe: str, *args: str) -> None:
    subprocess.run([exe, *args, "--quiet"], check=True)


def sitk_vectors(path: Path, indices: list[list[int]]) -> tuple[dict, list[list[float]]]:
    image = sitk.ReadImage(str(path))
    facts = {
        "pixel": image.GetPixelIDTypeAsString(),
        "components": image.GetNumberOfComponentsPerPixel(),
        "size": list(image.GetSize()),
    }
    assert facts["components"] == 3, facts
    return facts, [[float(v) for v in image.GetPixel(*ijk)] for ijk in indices]


def sitk_transform_points(path: Path, points: list[list[float]]) -> list[list[float]]:
    """x + D(x) at `points` (LPS mm) through ITK's DisplacementFieldTransform over the field as ReadImage read it."""
    field = sitk.Cast(sitk.ReadImage(str(path)), sitk.sitkVectorFloat64)
    transform = sitk.DisplacementFieldTransform(field)
    return [list(transform.TransformPoint(p)) for p in points]


def nibabel_vectors(path: Path, indices: list[list[int]]) -> tuple[dict, list[list[float]]]:
    img = nib.load(str(path))
    header = img.header
    data = np.asanyarray(img.dataobj)
    facts = {
        "intent_code": int(header["intent_code"]),
        "dim": [int(v) for v in header["dim"]],
        "datatype": int(header["datatype"]),
    }
    return facts, [[float(v) for v in data[i, j, k, 0, :]] for i, j, k in indices]


def centres(indices: list[list[int]]) -> list[list[float]]:
    image = sitk.ReadImage(str(VOLUME))
    return [list(image.TransformIndexToPhysicalPoint(ijk)) for ijk in indices]


def off_grid_points() -> list[list[float]]:
    image = sitk.ReadImage(str(VOLUME))
    return [list(image.TransformContinuousIndexToPhysicalPoint(c)) for c in OFF_GRID]


def mapped(exe: str, side: str, points: list[list[float]], tmp: Path) -> list[list[float]]:
    src, dst = tmp / f"{side}_in.csv", tmp / f"{side}_out.csv"
    src.write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
    run(exe, "points", "--fixed", str(VOLUME), "--moving", str(VOLUME), "--landmarks", str(PAIRS), "--from", side,
        "--in", str(src), "--out", str(dst), "--force")
    with dst.open() as f:
        return [[float(v) for v in row[:3]] for row in csv.reader(f)]


def max_diff(a: list[list[float]], b: list[list[float]]) -> float:
    return float(np.abs(np.array(a) - np.array(b)).max())


def main() -> None:
    exe = sys.argv[1]
    size = sitk.ReadImage(str(VOLUME)).GetSize()
    indices = [[i, j, k] for k in range(0, size[2], STRIDE) for j in range(0, size[1], STRIDE)
               for i in range(0, size[0], STRIDE)]
    xs = centres(indices)
    ps = off_grid_points()
    flavours = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        pullback = [[u - x for u, x in zip(ux, x)] for ux, x in zip(mapped(exe, "fixed", xs, tmp), xs)]
        forward = [[d - x for d, x in zip(dx, x)] for dx, x in zip(mapped(exe, "moving", xs, tmp), xs)]
        exact_off_grid = {"pullback": mapped(exe, "fixed", ps, tmp), "forward": mapped(exe, "moving", ps, tmp)}
        for name, file_name, flags in FLAVOURS:
            path = tmp / file_name
            run(exe, "field", "--fixed", str(VOLUME), "--moving", str(VOLUME), "--landmarks", str(PAIRS), *flags,
                "--out", str(path))
            expected = forward if name.endswith("forward") else pullback
            entry = {"name": name, "flags": flags}
            entry["sitk"], entry["sitk_vectors_lps"] = sitk_vectors(path, indices)
            diff = max_diff(entry["sitk_vectors_lps"], expected)
            if name.startswith("itk") or name == "ants":
                facts, raw = nibabel_vectors(path, indices)
                entry["nibabel"] = facts
                # nibabel gives the stored numbers: RAS for DISPVECT, LPS for VECTOR.
                lps = [[-v[0], -v[1], v[2]] for v in raw] if facts["intent_code"] == 1006 else raw
                entry["nibabel_vectors_lps"] = lps
                diff = max(diff, max_diff(lps, expected))
            print(f"{name}: max |reading − warpbench's map| {diff:.3g} mm at {len(indices)} voxels")
            assert diff <= TOLERANCE_MM, name
            entry["sitk_transform_point_lps"] = sitk_transform_points(path, ps)
            exact = exact_off_grid["forward" if name.endswith("forward") else "pullback"]
            off = max_diff(entry["sitk_transform_point_lps"], exact)
            print(f"{name}: DisplacementFieldTransform off the grid vs warpbench's exact map: {off:.3g} mm")
            assert off <= INTERPOLATION_MM, name
            flavours.append(entry)
    doc = {
        "made_by": "data-scripts/field_formats_ref.py",
        "simpleitk": sitk.Version.VersionString(),
        "nibabel": nib.__version__,
        "volume": "tests/data/nifti/avg152T1_LR_nifti.nii",
        "landmarks": "tests/data/itk/field_pairs.csv",
        "indices": indices,
        "off_grid_indices": OFF_GRID,
        "off_grid_points_lps": ps,
        "flavours": flavours,
    }
    lines = [json.dumps({k: v for k, v in doc.items() if k != "flavours"})[:-1] + ",", ' "flavours": [']
    lines += [" " + json.dumps(f) + ("," if n + 1 < len(flavours) else "") for n, f in enumerate(flavours)]
    lines += [" ]", "}"]
    OUT.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
