"""The cohort of docs/python.md on the repository's fixtures: three cases on the head MRI template, one with a
landmark outside the fixed volume, run twice on a LocalCluster of 2 workers (the rerun skips complete cases).

    python crates/python/examples/cohort.py [OUT_DIR]     # from the repository root
"""

import sys
import tempfile
from pathlib import Path

import warpbench as wb
from warpbench.batch import Case, format_table, run_cohort

HEAD = "tests/data/nifti/avg152T1_LR_nifti.nii"
PAIRS = "tests/data/itk/field_pairs.csv"

if __name__ == "__main__":  # Dask starts its workers by importing this file again
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="warpbench-cohort-"))
    out.mkdir(parents=True, exist_ok=True)
    pairs = wb.read_landmarks(PAIRS)
    bad = wb.Pairs(pairs.moving.copy(), pairs.fixed.copy(), names=list(pairs.names))
    bad.fixed[4] = [900.0, 0.0, 0.0]
    wb.write_landmarks(out / "bad.csv", bad)
    cases = [
        Case("s01", HEAD, HEAD, PAIRS, out=out / "s01.nii.gz", out_field=out / "s01_field.nii.gz"),
        Case("s02", HEAD, HEAD, PAIRS, out=out / "s02.nii.gz", method="affine"),
        Case("s03", HEAD, HEAD, out / "bad.csv", out=out / "s03.nii.gz"),
    ]
    print(format_table(run_cohort(cases, table=out / "results.csv")))
    print()
    print(format_table(run_cohort(cases)))
