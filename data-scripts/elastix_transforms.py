#!/usr/bin/env python3
"""elastix transform parameter files, and where transformix maps points through them:
tests/data/elastix/ and tests/data/elastix/transformix_reference.json.

Two parts, both run by elastix 5 through itk-elastix 0.25.4 (ITK 5.4.7):

1. **Files elastix wrote** (read by `--initial`): elastix registers two small synthetic volumes (two Gaussian blobs
   on a 1.5 mm grid, the moving one shifted, turned and scaled) and writes its transform parameter files as the
   `elastix` executable names and chains them:
   - `rigid.txt`: an `EulerTransform` (3 angles, ComputeZYX "false", then the translation, about
     CenterOfRotationPoint);
   - `rigid_zyx.txt`: `rigid.txt` with ComputeZYX "true" (the angles composed in the other order);
   - `similarity.txt`: a `SimilarityTransform` (versor, translation, scale);
   - `affine.txt`: an `AffineTransform` whose InitialTransformParameterFileName is `rigid.txt` (composed: the
     affine applied after the rigid), as `elastix -p rigid -p affine` writes `TransformParameters.1.txt`;
   - `translation.txt`: a `TranslationTransform`;
   - `bspline.txt`: a cubic `BSplineTransform` (8 mm control grid) whose InitialTransformParameterFileName is
     `affine.txt`, as `elastix -p rigid -p affine -p bspline` writes `TransformParameters.2.txt`: the three-stage
     registration's first two stages are checked to be `rigid.txt` and `affine.txt`. Its coefficients are elastix's
     plus a seeded bump (σ 1.5 mm), since two blobs leave an elastix B-spline little to do;
   - `bspline_oblique.txt`: written by data-scripts/elastix_field.py (run it first): the B-spline over an oblique
     grid whose transformix field is tests/data/metaimage/transformix_field.mhd.
   transformix maps 20 fixed points through each (`outputpoints.txt`, its `OutputPoint`), recorded per file; for
   `bspline.txt` also 12 points outside the fixed box (where the B-spline ends) and every third voxel centre of the
   fixed grid (1 000), for the field warpbench samples from it.
2. **Files warpbench writes** (`warpbench transform --format elastix`): on tests/data/nifti/avg152T1_LR_nifti.nii
   with the pairs tests/data/itk/field_pairs.csv, for `--method tps`, `tps --stiffness 5`, `hbspline` and `affine`,
   the script has warpbench write the file, has transformix map 100 points of the fixed box through it, and compares
   them with `warpbench points --from fixed` (the pull-back u): they must agree within 1e-6 mm (measured in the
   output). It records each file's sha256 and transformix's points, so the Rust test can require that the file it
   writes is the one transformix read, and that warpbench's map is transformix's at those points.

Deterministic: a rerun writes the same bytes (elastix runs with a fixed RandomSeed and one thread). Run from the
repository root, with itk-elastix==0.25.4 installed (data-cache/elastix-venv):

    data-cache/elastix-venv/bin/python data-scripts/elastix_transforms.py target/debug/warpbench
"""

from __future__ import annotations

import csv
import hashlib
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import itk
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "elastix"
VOLUME = ROOT / "tests" / "data" / "nifti" / "avg152T1_LR_nifti.nii"
PAIRS = ROOT / "tests" / "data" / "itk" / "field_pairs.csv"
AGREE_MM = 1e-6


def blobs(shift, angle_deg, scale):
    """A 28³ volume at 1.5 mm of two Gaussian blobs, the second placed by rotating its offset by `angle_deg` about
    z, scaling it by `scale` and shifting both by `shift` (mm)."""
    n, s = 28, 1.5
    z, y, x = (np.mgrid[0:n, 0:n, 0:n] * s).astype(np.float64)
    a = np.radians(angle_deg)
    c0 = np.array([20.0, 21.0, 19.0]) + shift
    off = scale * np.array([np.cos(a) * -8.0 - np.sin(a) * 6.0, np.sin(a) * -8.0 + np.cos(a) * 6.0, -4.0])
    one = np.exp(-((x - c0[0]) ** 2 + (y - c0[1]) ** 2 + (z - c0[2]) ** 2) / (2 * (4.0 * scale) ** 2))
    two = 0.6 * np.exp(-((x - c0[0] - off[0]) ** 2 + (y - c0[1] - off[1]) ** 2 + (z - c0[2] - off[2]) ** 2)
                       / (2 * (2.5 * scale) ** 2))
    image = itk.image_from_array((one + two).astype(np.float32))
    image.SetSpacing((s, s, s))
    image.SetOrigin((-3.0, 2.0, 1.5))
    return image


def register(maps: list[dict]) -> itk.ParameterObject:
    fixed = blobs(np.zeros(3), 0.0, 1.0)
    moving = blobs(np.array([2.2, -1.4, 0.9]), 9.0, 1.06)
    po = itk.ParameterObject.New()
    for kind, extra in maps:
        m = po.GetDefaultParameterMap(kind, 2)
        m["MaximumNumberOfIterations"] = ["200"]
        m["RandomSeed"] = ["20261205"]
        for k, v in extra.items():
            m[k] = [v]
        po.AddParameterMap(m)
    method = itk.ElastixRegistrationMethod.New(fixed, moving, ParameterObject=po, LogToConsole=False)
    method.SetNumberOfThreads(1)
    method.Update()
    return method.GetTransformParameterObject()


def write_map(m, path: Path) -> None:
    itk.ParameterObject.WriteParameterFile(m, str(path))


def transformix_points_through(objects: itk.ParameterObject, points: list[list[float]],
                               image: itk.Image) -> list[list[float]]:
    """transformix's `OutputPoint` for `points` (LPS mm) through the transforms of `objects`, first map first."""
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        inputs = tmp / "inputpoints.txt"
        inputs.write_text("point\n%d\n" % len(points) + "".join(" ".join(repr(float(v)) for v in p) + "\n"
                                                             for p in points))
        f = itk.TransformixFilter.New(Input=image, TransformParameterObject=objects)
        f.SetFixedPointSetFileName(str(inputs))
        f.SetOutputDirectory(str(tmp))
        f.SetComputeDeformationField(False)
        f.Update()
        text = (tmp / "outputpoints.txt").read_text()
    out = [[float(v) for v in m.split()] for m in re.findall(r"OutputPoint = \[ ([^\]]*)\]", text)]
    assert len(out) == len(points)
    return out


def chain_object(parameter_file: Path) -> itk.ParameterObject:
    """The chain that starts at `parameter_file` as one parameter object, its initial transform first."""
    chain = [parameter_file]
    while True:
        po = itk.ParameterObject.New()
        po.ReadParameterFile(str(chain[0]))
        initial = po.GetParameterMap(0)["InitialTransformParameterFileName"][0]
        if initial in ("NoInitialTransform", ""):
            break
        chain.insert(0, chain[0].parent / initial)
    objects = itk.ParameterObject.New()
    for p in chain:
        one = itk.ParameterObject.New()
        one.ReadParameterFile(str(p))
        m = one.GetParameterMap(0)
        m["InitialTransformParameterFileName"] = ["NoInitialTransform"]
        objects.AddParameterMap(m)
    return objects


def transformix_points(parameter_file: Path, points: list[list[float]], image: itk.Image) -> list[list[float]]:
    """transformix's `OutputPoint` for `points` (LPS mm) through the chain that starts at `parameter_file`."""
    return transformix_points_through(chain_object(parameter_file), points, image)


def run(exe: str, *args: str) -> None:
    subprocess.run([exe, *args, "--quiet"], check=True)


def main() -> None:
    exe = sys.argv[1]
    OUT.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(20261205)
    reference: dict = {"made_by": "data-scripts/elastix_transforms.py", "itk": itk.Version.GetITKVersion(),
                       "itk_elastix": "0.25.4", "elastix_files": [], "warpbench_files": []}

    # 1. Files elastix wrote.
    small_points = (rng.uniform([-3.0, 2.0, 1.5], [37.5, 42.5, 42.0], size=(20, 3))).tolist()
    grid = blobs(np.zeros(3), 0.0, 1.0)
    chained = register([("rigid", {}), ("affine", {})])
    rigid, affine = chained.GetParameterMap(0), chained.GetParameterMap(1)
    rigid["InitialTransformParameterFileName"] = ["NoInitialTransform"]
    affine["InitialTransformParameterFileName"] = ["rigid.txt"]
    write_map(rigid, OUT / "rigid.txt")
    write_map(affine, OUT / "affine.txt")
    # elastix's optimiser keeps ComputeZYX "false"; the same angles read the other way are another rotation, which
    # transformix applies as the file says.
    rigid["ComputeZYX"] = ["true"]
    write_map(rigid, OUT / "rigid_zyx.txt")
    for name, kind, extra in [("similarity.txt", "rigid", {"Transform": "SimilarityTransform"}),
                              ("translation.txt", "translation", {})]:
        m = register([(kind, extra)]).GetParameterMap(0)
        m["InitialTransformParameterFileName"] = ["NoInitialTransform"]
        write_map(m, OUT / name)
    staged = register([("rigid", {}), ("affine", {}),
                       ("bspline", {"FinalGridSpacingInPhysicalUnits": "8", "NumberOfResolutions": "2"})])
    for k, mine in [(0, rigid), (1, affine)]:
        theirs = staged.GetParameterMap(k)
        assert theirs["TransformParameters"] == mine["TransformParameters"], f"stage {k} differs"
    bspline = staged.GetParameterMap(2)
    bspline["InitialTransformParameterFileName"] = ["affine.txt"]
    # Its own generator, so that the points drawn below are those of the files before it.
    extra = np.random.default_rng(20261206)
    bump = extra.standard_normal(len(bspline["TransformParameters"])) * 1.5
    bspline["TransformParameters"] = [repr(float(v) + float(b)) for v, b in zip(bspline["TransformParameters"], bump)]
    write_map(bspline, OUT / "bspline.txt")
    for name in ["rigid.txt", "rigid_zyx.txt", "similarity.txt", "affine.txt", "translation.txt", "bspline.txt",
                 "bspline_oblique.txt"]:
        mapped = transformix_points(OUT / name, small_points, grid)
        moved = max(float(np.linalg.norm(np.subtract(a, b))) for a, b in zip(mapped, small_points))
        print(f"{name}: transformix moves the points by up to {moved:.2f} mm")
        one = itk.ParameterObject.New()
        one.ReadParameterFile(str(OUT / name))
        kind = one.GetParameterMap(0)["Transform"][0]
        reference["elastix_files"].append({"file": name, "transform": kind, "linear": "BSpline" not in kind,
                                           "transformix_lps": mapped})
    reference["elastix_points_lps"] = small_points
    outside = extra.uniform([-40.0, -35.0, -35.0], [80.0, 80.0, 80.0], size=(40, 3))
    box_lo, box_hi = np.array([-3.0, 2.0, 1.5]), np.array([-3.0, 2.0, 1.5]) + 27 * 1.5
    outside = [p for p in outside.tolist() if np.any(np.array(p) < box_lo) or np.any(np.array(p) > box_hi)][:12]
    indices = [[i, j, k] for k in range(0, 28, 3) for j in range(0, 28, 3) for i in range(0, 28, 3)]
    centres = [list(grid.TransformIndexToPhysicalPoint(ijk)) for ijk in indices]
    reference["bspline_chain"] = {
        "file": "bspline.txt", "outside_lps": outside,
        "transformix_outside_lps": transformix_points(OUT / "bspline.txt", outside, grid),
        "indices": indices, "centres_lps": centres,
        "transformix_centres_lps": transformix_points(OUT / "bspline.txt", centres, grid)}
    moved = max(float(np.linalg.norm(np.subtract(a, b)))
                for a, b in zip(reference["bspline_chain"]["transformix_centres_lps"], centres))
    # transformix resamples the moving blobs through the chain, linearly, onto the fixed grid.
    moving = blobs(np.array([2.2, -1.4, 0.9]), 9.0, 1.06)
    objects = chain_object(OUT / "bspline.txt")
    for k in range(objects.GetNumberOfParameterMaps()):
        objects.SetParameter(k, "ResampleInterpolator", "FinalLinearInterpolator")
        objects.SetParameter(k, "ResultImagePixelType", "float")
    with tempfile.TemporaryDirectory() as tmp_name:
        resampled = itk.transformix_filter(moving, objects, output_directory=tmp_name)
    itk.imwrite(moving, str(OUT / "moving_blobs.nii.gz"), compression=True)
    itk.imwrite(resampled, str(OUT / "transformix_bspline_result.nii.gz"), compression=True)
    print(f"bspline.txt: transformix moves the voxel centres by up to {moved:.2f} mm")

    # 2. Files warpbench writes, read by transformix.
    fixed = itk.imread(str(VOLUME), itk.F)
    lo = np.array(fixed.TransformIndexToPhysicalPoint([0, 0, 0]))
    hi = np.array(fixed.TransformIndexToPhysicalPoint([int(n) - 1 for n in fixed.GetLargestPossibleRegion().GetSize()]))
    box_lo, box_hi = np.minimum(lo, hi), np.maximum(lo, hi)
    points = rng.uniform(box_lo, box_hi, size=(100, 3)).tolist()
    reference["warpbench_points_lps"] = points
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        (tmp / "in.csv").write_text("".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in points))
        for name, flags in [("tps", ["--method", "tps"]), ("tps_stiff", ["--method", "tps", "--stiffness", "5"]),
                            ("hbspline", ["--method", "hbspline"]), ("affine", ["--method", "affine"])]:
            path = tmp / f"{name}.txt"
            common = ["--fixed", str(VOLUME), "--moving", str(VOLUME), "--landmarks", str(PAIRS), *flags]
            run(exe, "transform", *common, "--format", "elastix", "--out", str(path))
            run(exe, "points", *common, "--from", "fixed", "--in", str(tmp / "in.csv"), "--out",
                str(tmp / f"{name}.csv"), "--force")
            with (tmp / f"{name}.csv").open() as f:
                ours = [[float(v) for v in row[:3]] for row in csv.reader(f)]
            theirs = transformix_points(path, points, fixed)
            worst = max(float(np.abs(np.subtract(a, b)).max()) for a, b in zip(ours, theirs))
            moved = max(float(np.linalg.norm(np.subtract(a, b))) for a, b in zip(theirs, points))
            print(f"warpbench {name}: transformix vs warpbench's pull-back at {len(points)} points: {worst:.3g} mm "
                  f"(points moved up to {moved:.2f} mm)")
            assert worst <= AGREE_MM, (name, worst)
            reference["warpbench_files"].append({
                "name": name, "flags": flags, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                "transformix_lps": theirs, "max_difference_mm": worst})
    (OUT / "transformix_reference.json").write_text(json.dumps(reference) + "\n")


if __name__ == "__main__":
    main()
