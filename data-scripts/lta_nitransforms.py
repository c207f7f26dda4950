#!/usr/bin/env python3
"""FreeSurfer's LTA files, as FreeSurfer wrote them, and what nitransforms reads from them.

nitransforms 25.1.0 ships, among its test data, LTA files that FreeSurfer's own programs wrote (bbregister,
mri_robust_register, lta_convert, mri_concatenate_lta: each file's comment says which) beside the ITK `.tfm` files of
the same transforms, and a few LTAs nitransforms wrote itself. This script copies them from the installed package
into tests/data/lta/ (under their own names, `regressions/` flattened to a `regressions_` prefix) and writes
`reference.json`: for each LTA, the matrix nitransforms reads (`FSLinearTransformArray.from_filename(f).to_ras()`:
the pull-back, fixed points to moving points, in RAS, where the fixed volume is the LTA's dst and the moving one its
src) and the voxel-to-RAS matrices of its src and dst geometries (`VolumeGeometry.as_affine()`).

Usage, from the repository root (a Python with nitransforms 25.1.0, nibabel 5.4.2 and numpy 2.4.6, e.g. the venv
`.ci/run` makes):

    target/ci-python-venv/bin/python data-scripts/lta_nitransforms.py
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import nitransforms
from nitransforms.io import lta
import numpy as np

OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "lta"
DATA = Path(nitransforms.__file__).parent / "tests" / "data"
LTAS = [
    "bold-to-t1w.lta",
    "bold-to-t1w.v2v.lta",
    "affine-RAS.fs.lta",
    "affine-RAS.fs.v2v.lta",
    "affine-oblique.fs.lta",
    "regressions/from-fsnative_to-bold_mode-image.lta",
    "regressions/from-fsnative_to-bold_mode-image_type-ras2ras.lta",
    "regressions/from-scanner_to-bold_mode-image.lta",
    "regressions/from-scanner_to-bold_mode-image_type-ras2ras.lta",
    "regressions/from-fsnative_to-scanner_mode-image.lta",
    "regressions/from-scanner_to-fsnative_mode-image.lta",
]
TFMS = [
    "regressions/from-fsnative_to-bold_mode-image.tfm",
    "regressions/from-scanner_to-bold_mode-image.tfm",
    "regressions/from-fsnative_to-scanner_mode-image.tfm",
    "regressions/from-scanner_to-fsnative_mode-image.tfm",
]


def local(name: str) -> str:
    return name.replace("regressions/", "regressions_")


def main() -> None:
    assert nitransforms.__version__ == "25.1.0", nitransforms.__version__
    OUT.mkdir(parents=True, exist_ok=True)
    reference = {"nitransforms": nitransforms.__version__, "ltas": {}}
    for name in LTAS + TFMS:
        shutil.copyfile(DATA / name, OUT / local(name))
    for name in LTAS:
        array = lta.FSLinearTransformArray.from_filename(OUT / local(name))
        xform = array["xforms"][0]
        geometries = {}
        for side in ("src", "dst"):
            geometry = xform[side]
            if int(geometry["valid"]):
                geometries[side] = geometry.as_affine().tolist()
        reference["ltas"][local(name)] = {
            "type": int(array["type"]),
            "ras_moving_from_fixed": np.asarray(array.to_ras()[0]).tolist(),
            "ras_from_index": geometries,
        }
    (OUT / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")


if __name__ == "__main__":
    main()
