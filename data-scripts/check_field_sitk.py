#!/usr/bin/env python3
"""Check a `warpbench field` output (and a `--tfm`) with an independent reader: SimpleITK.

SimpleITK reads the NIfTI displacement field with ITK's own NIfTI reader (which takes the DISPVECT vectors from
RAS to LPS) and builds a DisplacementFieldTransform, T(x) = x + D(x) with D interpolated linearly between voxel
centres. The script computes nothing with warpbench's code:

- at each landmark pair (p_i moving, q_i fixed; BigWarp CSV, LPS mm = ITK physical space) it reports
  |T(q_i) - p_i|: about 0 for an interpolating warp (TPS with stiffness 0) when q_i is a voxel centre, and the
  linear-interpolation error of the field otherwise;
- it applies T at the voxel centres of a strided sub-grid (a few hundred points, positions from ITK's own reading
  of the geometry) and writes (index, x, T(x)) to --out, so that a Rust test can compare ITK's reading with the
  exact pull-back u(x) (crates/app/tests/field_cli.rs);
- with --tfm it reads the ITK transform file, applies it at the landmarks and the same points, and reports the
  difference from the field (meaningful when both were written for the same linear warp).

Usage (from the repository root; see tests/data/PROVENANCE.md, "ITK displacement-field reference"):

    data-cache/venv/bin/python data-scripts/check_field_sitk.py --landmarks L.csv --field F.nii.gz \
        [--tfm T.tfm] [--stride 13] [--out reference.json]

Exit status 1 when the field's metadata is not a 3-vector DISPVECT field.
"""

import argparse
import csv
import hashlib
import json
import math
import os
import sys

import SimpleITK as sitk


def sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def read_pairs(path):
    """BigWarp CSV: name, active, moving x y z, fixed x y z (LPS mm)."""
    pairs = []
    with open(path, newline="") as f:
        for row in csv.reader(f):
            if not row or row[1].strip().lower() != "true":
                continue
            p = [float(v) for v in row[2:5]]
            q = [float(v) for v in row[5:8]]
            pairs.append({"name": row[0], "moving": p, "fixed": q})
    return pairs


def dist(a, b):
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)))


def rel(path):
    return os.path.relpath(path).replace(os.sep, "/")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--landmarks", required=True)
    ap.add_argument("--field")
    ap.add_argument("--tfm")
    ap.add_argument("--stride", type=int, default=13)
    ap.add_argument("--out")
    args = ap.parse_args()
    if not args.field and not args.tfm:
        ap.error("give --field, --tfm or both")

    pairs = read_pairs(args.landmarks)
    report = {
        "generator": "data-scripts/check_field_sitk.py",
        "simpleitk_version": sitk.Version.VersionString(),
        "itk_version": sitk.Version.ITKVersionString(),
        "landmarks": {"path": rel(args.landmarks), "sha256": sha256(args.landmarks)},
        "note": "LPS mm (ITK physical space); floats are Python repr (round-trip exact)",
    }

    field_tx = None
    points = []
    if args.field:
        img = sitk.ReadImage(args.field, sitk.sitkVectorFloat64)
        intent = img.GetMetaData("intent_code") if img.HasMetaDataKey("intent_code") else None
        if intent != "1006" or img.GetNumberOfComponentsPerPixel() != 3 or img.GetDimension() != 3:
            print(f"{args.field}: intent_code {intent}, {img.GetNumberOfComponentsPerPixel()} components, "
                  f"{img.GetDimension()}-D: not a 3-D DISPVECT field", file=sys.stderr)
            return 1
        size = img.GetSize()
        index_points = [
            (i, j, k)
            for k in range(0, size[2], args.stride)
            for j in range(0, size[1], args.stride)
            for i in range(0, size[0], args.stride)
        ]
        points = [list(img.TransformIndexToPhysicalPoint(idx)) for idx in index_points]
        field_tx = sitk.DisplacementFieldTransform(sitk.Image(img))
        mapped = [list(field_tx.TransformPoint(x)) for x in points]
        errs = [dist(field_tx.TransformPoint(pr["fixed"]), pr["moving"]) for pr in pairs]
        report["field"] = {
            "file": os.path.basename(args.field),
            "sha256": sha256(args.field),
            "size": list(size),
            "origin_lps": list(img.GetOrigin()),
            "spacing_mm": list(img.GetSpacing()),
            "direction": list(img.GetDirection()),
            "intent_code": intent,
            "landmarks": [
                {"name": pr["name"], "fixed": pr["fixed"], "moving": pr["moving"],
                 "mapped": list(field_tx.TransformPoint(pr["fixed"])), "error_mm": e}
                for pr, e in zip(pairs, errs)
            ],
            "landmark_max_error_mm": max(errs) if errs else None,
            "grid": [{"index": list(idx), "x": x, "mapped": y} for idx, x, y in zip(index_points, points, mapped)],
        }
        print(f"field {args.field}: {size}, intent {intent}; |T(q_i) - p_i| over {len(pairs)} landmarks: "
              f"max {max(errs):.3e} mm, mean {sum(errs) / len(errs):.3e} mm; {len(points)} grid points recorded")

    if args.tfm:
        tfm_tx = sitk.ReadTransform(args.tfm)
        errs = [dist(tfm_tx.TransformPoint(pr["fixed"]), pr["moving"]) for pr in pairs]
        entry = {
            "file": os.path.basename(args.tfm),
            "sha256": sha256(args.tfm),
            "landmarks": [
                {"name": pr["name"], "fixed": pr["fixed"], "mapped": list(tfm_tx.TransformPoint(pr["fixed"]))}
                for pr in pairs
            ],
            "landmark_rms_residual_mm": math.sqrt(sum(e * e for e in errs) / len(errs)),
        }
        print(f"tfm {args.tfm}: RMS |T(q_i) - p_i| = {entry['landmark_rms_residual_mm']:.4f} mm (the fit's residual)")
        if field_tx is not None:
            diffs = [dist(tfm_tx.TransformPoint(x), field_tx.TransformPoint(x)) for x in points]
            entry["max_field_difference_mm"] = max(diffs)
            print(f"tfm vs field at {len(points)} voxel centres: max {max(diffs):.3e} mm")
        report["tfm"] = entry

    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, separators=(",", ":"))
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
