#!/usr/bin/env bash
# Seeds each fuzz target's corpus with the small committed fixtures (files under 2 MB).
set -euo pipefail
cd "$(dirname "$0")"
data=../tests/data
seed() { mkdir -p "corpus/$1"; find "$data/$2" -type f -size -2M -name "$3" -exec cp {} "corpus/$1/" \; ; }
seed nifti nifti '*.nii*'
seed nrrd nrrd '*.n*'
seed dicom dicom '*.dcm'
seed landmarks landmarks '*'
