#!/usr/bin/env bash
# plastimatch's DICOM Spatial Registration for a known rigid transform between two of the committed DICOM series:
# tests/data/dicom_reg/. warpbench's REG for the same transform must hold the same matrix (crates/app/tests/dicom_export.rs).
#
# - start.tfm: an AffineTransform (a rotation of Euler angles 0.05, -0.03, 0.14 rad about (-68.5, -139.3, 3.76) and a
#   translation of (0.8, 52, -2.9) mm) written by SimpleITK 2.5.7, mapping the CT's points to the MR's;
# - plastimatch_reg.dcm: `plastimatch xf-convert` (plastimatch 1.9.4, Debian bookworm's package) of start.tfm with
#   the CT series tests/data/dicom/pydicom_ct5n as the fixed frame and tests/data/dicom/mixed_ct5n_mr_small/MR_small.dcm
#   as the moving one. plastimatch prints the matrix with 6 decimals and names new UIDs, so only the matrix is compared;
# - pairs.csv: five hand-made BigWarp pairs from the MR's slab into the CT's box, and plastimatch_dsr.dcm (below).
#
# Usage, from the repository root, with plastimatch installed (apt-get install plastimatch) and SimpleITK 2.5.7 in
# target/ci-python-venv (.ci/run makes it):
#
#     bash data-scripts/plastimatch_reg.sh
set -euo pipefail
out=tests/data/dicom_reg
mkdir -p "$out"
cat >"$out/pairs.csv" <<'CSV'
"Pt-0","true","-71","-88","6.4","-70.5","-140","6.7"
"Pt-1","true","-66","-88","6.9","-65.5","-140","7.2"
"Pt-2","true","-69","-84","6.9","-68.5","-136","7.2"
"Pt-3","true","-67","-85.5","6.4","-66.5","-137.5","6.7"
"Pt-4","true","-68","-86","6.6","-67.6","-138.2","6.9"
CSV
target/ci-python-venv/bin/python - <<'PY'
import SimpleITK as sitk
e = sitk.Euler3DTransform((-68.5, -139.3, 3.76), 0.05, -0.03, 0.14, (0.8, 52.0, -2.9))
sitk.WriteTransform(sitk.AffineTransform(e.GetMatrix(), e.GetTranslation(), e.GetCenter()), "tests/data/dicom_reg/start.tfm")
PY
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir "$work/mr"
cp tests/data/dicom/mixed_ct5n_mr_small/MR_small.dcm "$work/mr/"
plastimatch xf-convert --input "$out/start.tfm" --output-dicom "$work/sro" \
    --fixed-rcs tests/data/dicom/pydicom_ct5n --moving-rcs "$work/mr" >/dev/null
cp "$work"/sro/sro_*.dcm "$out/plastimatch_reg.dcm"
plastimatch --version

# The deformable case: warpbench's pull-back for the TPS through tests/data/dicom_reg/pairs.csv, sampled on the CT's
# grid (`warpbench field`, built first with `cargo build -p warpbench-app`), and plastimatch's Deformable Spatial
# Registration of that field between the same two series: plastimatch_dsr.dcm.
target/debug/warpbench field --fixed tests/data/dicom/pydicom_ct5n --moving tests/data/dicom/mixed_ct5n_mr_small/MR_small.dcm \
    --landmarks "$out/pairs.csv" --method tps --format metaimage --out "$work/vf.mha" --force --quiet
plastimatch xf-convert --input "$work/vf.mha" --output-dicom "$work/dsr" \
    --fixed-rcs tests/data/dicom/pydicom_ct5n --moving-rcs "$work/mr" >/dev/null
cp "$work"/dsr/dro_*.dcm "$out/plastimatch_dsr.dcm"
