"""The grids the nibabel and nitransforms fixture scripts build their volumes on (imported by
`fsl_flirt_nitransforms.py`, `mgh_nibabel.py` and `nifti_pair_nibabel.py`, run from the repository root as
`python data-scripts/NAME.py`, which puts this folder on the import path)."""

from __future__ import annotations

import numpy as np


def rotation(ax: float, ay: float, az: float) -> np.ndarray:
    """Rz(az) · Ry(ay) · Rx(ax), angles in radians."""
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def affine(linear: np.ndarray, origin) -> np.ndarray:
    """The 4 x 4 voxel-to-world matrix of `linear` (3 x 3) and `origin`, the position of voxel (0, 0, 0)."""
    a = np.eye(4)
    a[:3, :3] = linear
    a[:3, 3] = origin
    return a
