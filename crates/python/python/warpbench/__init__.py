"""warpbench from Python: landmark-based registration of 3D medical volumes.

Every number comes from the code the ``warpbench`` command line runs, in this process: a function and its CLI
twin give the same numbers on the same inputs and write the same bytes.

Coordinates are LPS millimetres (ITK's and DICOM's patient space). A volume's array is in i-j-k order as stored
(shape ``(ni, nj, nk)``, Fortran order, as nibabel presents NIfTI), and ``lps_from_index`` maps voxel indices to
LPS.

>>> import warpbench as wb
>>> fixed = wb.read_volume("ct.nii.gz")
>>> moving = wb.read_volume("mr.nii.gz")
>>> pairs = wb.read_landmarks("landmarks.csv")
>>> warp = wb.fit(pairs, method="tps", fixed=fixed, moving=moving)
>>> warp.leave_one_out()["mean_mm"]
>>> warp.resample(moving).write("mr_in_ct.nii.gz")

Errors are ``ValueError`` (bad input: the message names the file or the landmark, 1-based, and the problem),
``OSError`` (a file the system refuses) and ``RuntimeError`` (a bug; a panic in Rust never takes the interpreter
down). Long work releases the GIL.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import ExitStack
from dataclasses import dataclass, field as dataclass_field
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np

from . import _warpbench

__version__: str = _warpbench.__version__

PathLike = Union[str, "os.PathLike[str]"]

__all__ = [
    "Volume",
    "Pairs",
    "Warp",
    "Field",
    "read_volume",
    "write_volume",
    "read_field",
    "read_landmarks",
    "write_landmarks",
    "fit",
    "align",
    "register",
    "suggest",
    "run_cli",
]

# The sample types a volume keeps; the others convert as the readers convert them (docs/formats.md).
_KEPT = (np.uint8, np.int16, np.uint16, np.float32)


class Volume:
    """A 3-D volume placed in LPS space.

    Attributes:
        array: the samples, shape ``(ni, nj, nk)``, uint8, int16, uint16 or float32 (after any rescale).
        lps_from_index: 4×4 float64, voxel index (i, j, k, 1) to LPS mm.
        modality: ``"CT"``, ``"MR"``, another DICOM code, or ``None``.
        path: the file it was read from, if any.
        header: what the reader found (geometry source, rescale, metadata, warnings).
    """

    def __init__(
        self,
        array: np.ndarray,
        lps_from_index: np.ndarray,
        *,
        modality: Optional[str] = None,
        path: Optional[PathLike] = None,
        header: Optional[Dict[str, Any]] = None,
    ) -> None:
        self.array = array
        self.lps_from_index = np.asarray(lps_from_index, dtype=np.float64)
        self.modality = modality
        self.path = Path(path) if path is not None else None
        self.header = header or {}

    @classmethod
    def from_array(
        cls, array: np.ndarray, lps_from_index: np.ndarray, *, modality: Optional[str] = None
    ) -> "Volume":
        """A volume from an (ni, nj, nk) array and its 4×4 ``lps_from_index``.

        uint8, int16, uint16 and float32 are kept (no copy); bool becomes uint8, int8 int16, and the other types
        float32, as the readers convert them.
        """
        a = np.asarray(array)
        if a.ndim != 3:
            raise ValueError(f"a volume is a 3-D array (ni, nj, nk), not shape {a.shape}")
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        elif a.dtype == np.int8:
            a = a.astype(np.int16)
        elif a.dtype.type not in _KEPT:
            a = a.astype(np.float32)
        m = np.asarray(lps_from_index, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"lps_from_index must be 4×4, not shape {m.shape}")
        return cls(a, m, modality=modality)

    @classmethod
    def from_nibabel(cls, image: Any) -> "Volume":
        """A volume from a nibabel image (its affine is RAS: LPS = diag(-1, -1, 1) · RAS)."""
        ras = np.asarray(image.affine, dtype=np.float64)
        return cls.from_array(np.asanyarray(image.dataobj), np.diag([-1.0, -1.0, 1.0, 1.0]) @ ras)

    @classmethod
    def from_sitk(cls, image: Any) -> "Volume":
        """A volume from a SimpleITK image (whose physical space is LPS)."""
        import SimpleITK as sitk  # optional

        array = sitk.GetArrayViewFromImage(image).T  # (k, j, i) C order -> (i, j, k) Fortran order, no copy
        direction = np.array(image.GetDirection(), dtype=np.float64).reshape(3, 3)
        m = np.eye(4)
        m[:3, :3] = direction @ np.diag(image.GetSpacing())
        m[:3, 3] = image.GetOrigin()
        return cls.from_array(np.array(array, copy=True, order="F"), m)

    @property
    def shape(self) -> Tuple[int, int, int]:
        """Voxels along i, j, k."""
        return tuple(int(n) for n in self.array.shape)  # type: ignore[return-value]

    @property
    def spacing(self) -> np.ndarray:
        """Voxel spacing along i, j, k in mm (the lengths of ``lps_from_index``'s first three columns)."""
        return np.linalg.norm(self.lps_from_index[:3, :3], axis=0)

    @property
    def direction(self) -> np.ndarray:
        """The 3×3 direction cosines (columns: the i, j, k axes in LPS), as ITK's GetDirection."""
        return self.lps_from_index[:3, :3] / self.spacing

    @property
    def origin(self) -> np.ndarray:
        """The LPS position of voxel (0, 0, 0)'s centre, as ITK's GetOrigin."""
        return self.lps_from_index[:3, 3].copy()

    def write(self, path: PathLike) -> None:
        """Writes the volume as the command line does: NIfTI-1 (``.nii``, ``.nii.gz``), NRRD (``.nrrd``),
        MetaImage (``.mha``, ``.mhd``), FreeSurfer's MGH (``.mgh``, ``.mgz``), MINC 2 (``.mnc``) or OME-Zarr 0.5 (a folder named ``.ome.zarr``, for a grid
        along the patient axes), by the name, atomically (an interrupted write leaves no partial file)."""
        _warpbench.write_volume(os.fspath(path), self.array, self.lps_from_index, self.modality)

    def to_nibabel(self) -> Any:
        """A ``nibabel.Nifti1Image`` of the same samples and placement (needs nibabel)."""
        import nibabel as nib  # optional

        return nib.Nifti1Image(self.array, np.diag([-1.0, -1.0, 1.0, 1.0]) @ self.lps_from_index)

    def to_sitk(self) -> Any:
        """A ``SimpleITK.Image`` of the same samples and placement (needs SimpleITK)."""
        import SimpleITK as sitk  # optional

        image = sitk.GetImageFromArray(np.ascontiguousarray(self.array.T))
        image.SetSpacing([float(s) for s in self.spacing])
        image.SetOrigin([float(o) for o in self.origin])
        image.SetDirection([float(d) for d in self.direction.ravel()])
        return image

    def _grid(self) -> Tuple[List[int], np.ndarray]:
        return list(self.shape), self.lps_from_index

    def __repr__(self) -> str:
        where = f" from {self.path}" if self.path else ""
        return f"Volume({self.shape}, {self.array.dtype}, spacing {np.round(self.spacing, 4).tolist()} mm{where})"


def read_volume(path: PathLike, *, frame: Optional[int] = None, series: Optional[str] = None) -> Volume:
    """Reads a volume in any format the command line reads: NIfTI-1/2, NRRD, a DICOM series (folder or file),
    MetaImage, FreeSurfer's MGH/MGZ, MINC 1 and 2, an OME-Zarr folder (0.4 to 0.6), an AFNI dataset (its ``.HEAD``,
    ``.BRIK`` or ``.BRIK.gz``). ``frame`` chooses one frame of a 4-D file (one sub-brick of an AFNI dataset);
    ``series`` one series of a DICOM folder that holds several, by its SeriesInstanceUID."""
    array, lps, header = _warpbench.read_volume(os.fspath(path), frame, series)
    info = json.loads(header)
    return Volume(array, lps, modality=info.get("modality"), path=path, header=info)


def write_volume(path: PathLike, volume: Volume) -> None:
    """``volume.write(path)``."""
    volume.write(path)


@dataclass(frozen=True)
class Field:
    """A displacement field read from a file (:func:`read_field`).

    ``array`` holds its vectors, LPS mm, shape ``(ni, nj, nk, 3)`` float32, at the voxel centres of the grid
    ``lps_from_index``; ``source`` is the file's flavour (``"itk"``, ``"ants"``, ``"nrrd"``, ``"metaimage"``),
    ``"elastix"`` for a transform parameter file, ``"itk_h5"`` for ITK's HDF5 transform file, ``"itk_tfm"`` for its
    text file (``.tfm``), ``"dicom"`` for a DICOM Deformable Spatial Registration, ``"learn2reg"`` for a Learn2Reg
    ``.npz`` (``"pullback"``) or ``"minc"`` for an MNI transform file's grid (``.xfm``: ``"forward"``, the moving
    volume's world to the fixed one's, or ``"pullback"`` with ``Invert_Flag``); ``direction`` is ``"pullback"`` or
    ``"forward"`` where the file says (NRRD; ``"pullback"`` for an ``.h5``, a ``.tfm`` or a DICOM registration,
    ``"forward"`` for an ``.h5`` holding only 3D Slicer's ``InverseDisplacementFieldTransform``), else ``None``, and
    then it is a pull-back, as ITK takes it. ``"ngff"`` is an OME-Zarr 0.6 field folder (RFC-5's ``displacements``);
    ``warnings`` says what its reader assumed where the file is silent (axes without a unit taken as mm, axes
    without an orientation as L, P, S). ``"fnirt"`` is an FSL FNIRT warp read against its reference and input
    (``"pullback"``, on the reference's grid). ``"afni"`` is AFNI's ``3dQwarp`` warp (``"pullback"``): a dataset whose
    sub-bricks are labelled ``x_delta``, ``y_delta``, ``z_delta``, or the same saved as NIfTI with AFNI's extension."""

    array: np.ndarray
    lps_from_index: np.ndarray
    source: str
    direction: Optional[str]
    warnings: Tuple[str, ...] = ()

    @property
    def shape(self) -> Tuple[int, int, int]:
        """The grid's voxels along i, j, k."""
        return tuple(int(n) for n in self.array.shape[:3])  # type: ignore[return-value]


def read_field(
    path: PathLike, fixed: Optional[Volume] = None, moving: Optional[Volume] = None, learn2reg: bool = False
) -> Field:
    """Reads a displacement field as ``warpbench warp --field`` reads it: ITK's or ANTs' NIfTI, Slicer's NRRD, a
    MetaImage vector image (transformix's ``deformationField.mhd``), or an elastix transform parameter file
    (``TransformParameters.N.txt`` and the files it names), sampled at every voxel centre of its fixed grid as
    ``transformix -def all`` would write it, or ITK's HDF5 transform file holding a displacement field (ANTs'
    ``Composite.h5``: the affine and the field together), sampled on that field's grid. An ITK transform file of
    B-splines (``.tfm``, a composite as SimpleITK writes it, or ``.h5``, as 3D Slicer saves one) gives no grid of its
    own: it is sampled on ``fixed``'s grid, and needs ``fixed`` and ``moving``.

    A Learn2Reg field (steps from the fixed image's voxels to the moving image's) needs the two volumes it was made
    for, ``fixed`` and ``moving``: it is read as the pull-back on the fixed grid, in LPS mm, with ``source``
    ``"learn2reg"``. An ``.npz`` is told by its content; the NIfTI form the challenge takes since 2022 (an (X, Y, Z, 3)
    array, ``disp_XXXX_YYYY.nii.gz``) says nothing of its units, so it is read so only with ``learn2reg=True``.

    An AFNI ``3dQwarp`` warp (``PREFIX_WARP+tlrc.HEAD`` with its ``.BRIK``, or ``PREFIX_WARP.nii.gz``) is read on its own
    grid as ``3dNwarpApply`` applies it, with ``source`` ``"afni"``.

    An FSL FNIRT warp (``fnirt --fout`` or ``convertwarp`` deformation fields, ``fnirt --cout`` cubic coefficients;
    told by its NIfTI intent) maps FSL's coordinates of its reference image to its input's: give the reference as
    ``fixed`` and the input as ``moving``. It is read as the pull-back on the fixed grid with ``source`` ``"fnirt"``;
    ``warnings`` says whether a deformation field was taken as relative displacements or absolute positions.

    Without the volumes either raises ``ValueError``."""
    if (fixed is None) != (moving is None):
        raise ValueError(f"{os.fspath(path)}: give both fixed and moving, or neither")
    pair = None if fixed is None or moving is None else (fixed._grid(), moving._grid())
    array, lps, source, direction, warnings = _warpbench.read_field(os.fspath(path), pair, learn2reg)
    return Field(array, lps, source, direction, tuple(warnings))


@dataclass
class Pairs:
    """Landmark pairs: N×3 LPS mm arrays of the moving and the fixed points (NaN where a half is not placed yet),
    their names and active flags, and where they came from (messages name it)."""

    moving: np.ndarray
    fixed: np.ndarray
    names: List[str] = dataclass_field(default_factory=list)
    active: np.ndarray = dataclass_field(default_factory=lambda: np.zeros(0, dtype=bool))
    source: str = "pairs"
    format: Optional[str] = None

    def __post_init__(self) -> None:
        self.moving = np.asarray(self.moving, dtype=np.float64).reshape(-1, 3)
        self.fixed = np.asarray(self.fixed, dtype=np.float64).reshape(-1, 3)
        n = len(self.moving)
        if not self.names:
            self.names = [f"Pt-{i}" for i in range(n)]
        if len(self.active) == 0 and n:
            self.active = np.ones(n, dtype=bool)
        self.active = np.asarray(self.active, dtype=bool)

    def __len__(self) -> int:
        return len(self.moving)

    def _arrays(self) -> Tuple[np.ndarray, np.ndarray, List[str], List[bool]]:
        return (
            np.ascontiguousarray(self.moving, dtype=np.float64),
            np.ascontiguousarray(self.fixed, dtype=np.float64),
            [str(n) for n in self.names],
            [bool(a) for a in self.active],
        )


def read_landmarks(path: PathLike, fixed_path: Optional[PathLike] = None, *, ras: bool = False) -> Pairs:
    """Reads landmark pairs: BigWarp CSV or JSON, a plain CSV of pairs, an MNI tag file (``.tag``: volume 1 the fixed
    points, volume 2 the moving ones), transformix's ``outputpoints.txt`` (the
    input points fixed, the output points moving), a window session (``.warpbench.json``), or with ``fixed_path``
    two point lists matched by order (``path`` the moving one): Slicer ``.mrk.json``/``.fcsv``, elastix point
    files (``point``, LPS mm) or MNI tag files of one volume. ``ras``: a BigWarp file's coordinates are RAS (BigWarp on NIfTI)."""
    moving, fixed, names, active, fmt = _warpbench.read_landmarks(
        os.fspath(path), None if fixed_path is None else os.fspath(fixed_path), ras
    )
    source = os.fspath(path) if fixed_path is None else f"{os.fspath(path)} + {os.fspath(fixed_path)}"
    return Pairs(moving, fixed, names, np.array(active, dtype=bool), source=source, format=fmt)


def write_landmarks(
    path: PathLike,
    pairs: Pairs,
    fixed_path: Optional[PathLike] = None,
    *,
    format: Optional[str] = None,
    ras: bool = False,
) -> None:
    """Writes pairs as ``warpbench landmarks --out`` does: BigWarp CSV (``.csv``) or JSON (``.json``), an MNI tag file
    (``.tag``), or ``format`` (``"bigwarp-csv"``, ``"bigwarp-json"``, ``"plain-csv"``, ``"mni-tag"``); with ``fixed_path`` two point lists
    (``path`` the moving one), each a Slicer ``.mrk.json``/``.fcsv`` or an elastix point file (``.txt``) by its
    name. ``ras``: BigWarp and plain CSV coordinates in RAS."""
    moving, fixed, names, active = pairs._arrays()
    _warpbench.write_landmarks(
        os.fspath(path),
        moving,
        fixed,
        names,
        active,
        None if fixed_path is None else os.fspath(fixed_path),
        format,
        ras,
    )


def _points(points: Any) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 1:
        p = p.reshape(1, -1)
    return np.ascontiguousarray(p)


class Warp:
    """Landmark pairs fitted by a method (on a starting transform): the pull-back u = moving_from_fixed and the
    forward map d = fixed_from_moving. Made by :func:`fit`."""

    def __init__(self, native: Any, pairs: Pairs, fixed: Optional[Volume], moving: Optional[Volume]) -> None:
        self._native = native
        self.pairs = pairs
        self.fixed = fixed
        self.moving = moving

    @property
    def method(self) -> str:
        """The method as fitted, e.g. ``tps``, ``tps(λ=12.5)``, ``affine``."""
        return self._native.method

    def pullback(self, points: Any) -> np.ndarray:
        """u(x) for N×3 fixed points (LPS mm): where each comes from in the moving volume (``warpbench points
        --from fixed``)."""
        return self._native.pullback(_points(points))

    def forward(self, points: Any) -> np.ndarray:
        """d(y) for N×3 moving points (LPS mm): where each appears in the fixed volume (``warpbench points
        --from moving``)."""
        return self._native.forward(_points(points))

    def field(
        self,
        reference: Optional[Volume] = None,
        *,
        direction: str = "pullback",
        path: Optional[PathLike] = None,
        format: str = "itk",
    ) -> np.ndarray:
        """The displacement field on ``reference``'s grid (default: the fixed volume for ``"pullback"``, the moving
        one for ``"forward"``): u(x) − x or d(y) − y, shape (ni, nj, nk, 3), float32 LPS vectors. With ``path``
        it is also written in ``format`` (``"itk"``: NIfTI DISPVECT, ``"ants"``, ``"nrrd"``, ``"metaimage"``: .mha or
        .mhd, as elastix writes fields, ``"minc"``: an MNI grid transform ``.xfm``, ``"ngff"``: an OME-Zarr 0.6 field
        folder, which a ``path`` ending ``.ome.zarr`` picks too), as ``warpbench field`` writes it; a ``path`` ending
        ``.h5`` (with ``"itk"``)
        is ITK's HDF5 transform file holding the field as a DisplacementFieldTransform. ``"learn2reg"`` (or a ``path``
        ending ``.npz``) writes Learn2Reg's field, the pull-back's steps from the reference's voxels to the moving
        volume's (``.npz`` float16, or ``.nii.gz`` float32), which needs the warp fitted with ``moving=``.
        ``"fnirt"`` writes FSL FNIRT's relative deformation field (``.nii`` or ``.nii.gz``), in the FSL coordinates
        of ``reference`` (``applywarp``'s ``--ref``) and of the moving volume (its ``--in``), which needs ``moving=``
        too: ``applywarp --ref=REF --in=MOVING --warp=PATH --rel`` applies it. ``"afni"`` writes AFNI's warp as
        ``3dQwarp`` saves one to NIfTI (``.nii`` or ``.nii.gz``: LPS vectors, AFNI's extension labelling them):
        ``3dNwarpApply -nwarp PATH -source MOVING -master REF`` applies it."""
        if reference is None:
            reference = self.fixed if direction == "pullback" else self.moving
        if reference is None:
            raise ValueError("field: give reference=, or fit the warp with fixed= and moving=")
        return self._native.field(
            reference._grid(),
            direction,
            None if path is None else os.fspath(path),
            format,
            None if self.moving is None else self.moving._grid(),
        )

    def jacobian(
        self,
        reference: Optional[Volume] = None,
        *,
        quantity: str = "det",
        direction: str = "pullback",
        path: Optional[PathLike] = None,
    ) -> np.ndarray:
        """A map of the pull-back on ``reference``'s grid (default: the fixed volume), as ``warpbench jacobian``
        writes it: det ∇u (``quantity="det"``: below 1 the warp squeezes, at or below 0 it folds) or |u(x) − x| in mm
        (``"magnitude"``) at every voxel centre, shape (ni, nj, nk), float32. ``direction="forward"`` maps the forward
        map d instead, on the moving volume's grid by default (det ∇d, |d(y) − y|), as ``warpbench jacobian
        --direction forward``. With ``path`` it is also written as a volume (``.nii``, ``.nii.gz``, ``.nrrd``,
        ``.mha``, ``.mhd``)."""
        if reference is None:
            reference = self.fixed if direction == "pullback" else self.moving
        if reference is None:
            raise ValueError("jacobian: give reference=, or fit the warp with fixed= and moving=")
        array = self._native.jacobian(reference._grid(), quantity, direction)
        if path is not None:
            Volume(array, reference.lps_from_index).write(path)
        return array

    def resample(
        self,
        moving: Optional[Volume] = None,
        reference: Optional[Volume] = None,
        *,
        interpolation: str = "linear",
        exact: bool = False,
        grid: int = 64,
        float: bool = False,
        outside: Optional[float] = None,
        backend: str = "cpu",
    ) -> Volume:
        """The moving volume resampled through the pull-back on ``reference``'s grid (default: the fixed
        volume's), as ``warpbench warp`` makes it: ``interpolation`` ``"nearest"``, ``"linear"`` or ``"cubic"``;
        ``exact`` evaluates the warp at every voxel instead of a ``grid``³ control texture; ``float`` writes
        float32 instead of the moving volume's type; ``outside`` is the value outside the moving volume (default
        −1024 for a CT, else 0); ``backend`` ``"cpu"``, ``"gpu"`` or ``"auto"``."""
        moving = moving if moving is not None else self.moving
        if moving is None:
            raise ValueError("resample: give the moving volume")
        ref = reference._grid() if reference is not None else None
        array, lps, report = self._native.resample(
            moving.array,
            moving.lps_from_index,
            ref,
            interpolation,
            exact,
            grid,
            float,
            outside,
            moving.modality,
            backend,
        )
        return Volume(array, lps, modality=moving.modality, header={"resample": json.loads(report)})

    def to_itk_tfm(self, path: PathLike) -> None:
        """Writes the pull-back as the ITK transform file that holds it exactly (thin-plate spline, B-spline,
        affine), as ``warpbench transform`` does: a text ``.tfm``, ITK's HDF5 file for a name ending ``.h5``, or
        ANTs' ``.mat`` (a linear warp) for one ending ``.mat``. A warp on an ``initial_field`` goes to an ``.h5``
        only, as ITK's composite of ``initial``, the field's own transforms and the fit over them (a TPS sampled on
        the fixed grid, which needs the warp fitted with ``fixed=`` and ``moving=``)."""
        self._native.to_itk_tfm(os.fspath(path))

    def to_fsl(self, path: PathLike) -> None:
        """Writes a linear warp (``affine``, ``similarity``, ``rigid``, or ``initial`` alone) as FSL's FLIRT matrix
        (``flirt -applyxfm -init``) between the volumes it was fitted with, the fixed one as FLIRT's ``-ref`` and the
        moving one as its ``-in``, as ``warpbench transform --format fsl`` does. Needs ``fixed=`` and ``moving=``."""
        self._native.to_fsl(os.fspath(path))

    def to_afni(self, path: PathLike) -> None:
        """Writes a linear warp as AFNI's matrix file (``.aff12.1D``, for ``3dAllineate -1Dmatrix_apply``), the fixed
        volume as AFNI's base and the moving one as its source, as ``warpbench transform --format afni`` does. Needs
        ``fixed=`` and ``moving=``, neither oblique."""
        self._native.to_afni(os.fspath(path))

    def to_xfm(self, path: PathLike) -> None:
        """Writes a linear warp as an MNI transform file (``.xfm``, for ``mincresample -transformation``): the map
        from the moving volume's world to the fixed one's, RAS mm, as ``warpbench transform --format minc`` does."""
        self._native.to_xfm(os.fspath(path))

    def to_lta(self, path: PathLike) -> None:
        """Writes a linear warp as FreeSurfer's LTA (``.lta``, ``LINEAR_RAS_TO_RAS``, for ``mri_vol2vol --lta``), the
        moving volume as its src and the fixed one as its dst, named by the files they were read from, as
        ``warpbench transform --format lta`` does. Needs ``fixed=`` and ``moving=``."""

        def name(volume: Optional[Volume]) -> str:
            return os.fspath(volume.path) if volume is not None and volume.path is not None else ""

        self._native.to_lta(os.fspath(path), name(self.fixed), name(self.moving))

    def to_elastix(self, path: PathLike, reference: Optional["Volume"] = None) -> None:
        """Writes the pull-back as the elastix transform parameter file that holds it exactly (``SplineKernelTransform``,
        ``BSplineTransform``, ``AffineTransform``), naming ``reference``'s grid (default: the fixed volume's) as
        where transformix resamples, as ``warpbench transform --format elastix`` does."""
        if reference is None:
            reference = self.fixed
        if reference is None:
            raise ValueError("to_elastix: give reference=, or fit the warp with fixed= and moving=")
        self._native.to_elastix(os.fspath(path), reference._grid())

    def to_dicom(self, path: PathLike, fixed: Optional["Volume"] = None, moving: Optional["Volume"] = None) -> str:
        """Writes the pull-back as a DICOM registration (one ``.dcm``, modality REG) from the moving DICOM series onto
        the fixed one, as ``warpbench transform --format dicom`` does: a Spatial Registration (a matrix from the
        moving series' patient coordinates to the fixed series') for a linear warp, else a Deformable Spatial
        Registration of the pull-back sampled on the fixed volume's grid. ``fixed`` and ``moving`` (default: the
        volumes the warp was fitted with) must have been read from DICOM series. Returns the matrix type (``RIGID``,
        ``RIGID_SCALE``, ``AFFINE``) or ``DEFORMABLE``."""
        fixed = self.fixed if fixed is None else fixed
        moving = self.moving if moving is None else moving
        if fixed is None or moving is None or fixed.path is None or moving.path is None:
            raise ValueError("to_dicom: give fixed= and moving= volumes read from DICOM series")
        return self._native.to_dicom(os.fspath(path), os.fspath(fixed.path), os.fspath(moving.path), fixed._grid())

    def leave_one_out(self) -> Dict[str, Any]:
        """Each fitted pair's residual and leave-one-out error (the pair left out, the rest refitted, the distance
        at which its fixed point is mapped from its moving point), as the window's landmark table shows them.

        Returns ``{"rows": 1-based rows, "names", "residual_mm", "leave_one_out_mm" (NaN where the refit failed),
        "mean_mm", "max_mm"}``."""
        rows, residuals, loo = [], [], []
        for row, residual, left_out in self._native.leave_one_out():
            rows.append(row)
            residuals.append(residual)
            loo.append(np.nan if left_out is None else left_out)
        loo_a = np.array(loo, dtype=np.float64)
        finite = loo_a[np.isfinite(loo_a)]
        return {
            "rows": rows,
            "names": [self.pairs.names[r - 1] for r in rows],
            "residual_mm": np.array(residuals, dtype=np.float64),
            "leave_one_out_mm": loo_a,
            "mean_mm": float(finite.mean()) if finite.size else float("nan"),
            "max_mm": float(finite.max()) if finite.size else float("nan"),
        }

    def folding(self, reference: Optional[Volume] = None, *, n: int = 64) -> Dict[str, Any]:
        """det ∇u at the centres of an n³ grid of cells over ``reference``'s box (default: the fixed volume's, or
        the fit's domain): ``{"min_det", "min_at", "max_det", "fraction_folded", "points", "folds"}``."""
        reference = reference if reference is not None else self.fixed
        grid = reference._grid() if reference is not None else None
        min_det, min_at, max_det, fraction, points = self._native.folding(grid, n)
        return {
            "min_det": min_det,
            "min_at": list(min_at),
            "max_det": max_det,
            "fraction_folded": fraction,
            "points": points,
            "folds": min_det <= 0.0,
        }

    @property
    def rows(self) -> List[int]:
        """The 1-based rows of the pairs the warp is fitted on (active, both points placed)."""
        return list(self._native.rows)

    def __repr__(self) -> str:
        return f"Warp({self.method}, {len(self.rows)} pairs)"


def fit(
    pairs: Pairs,
    method: str = "tps",
    stiffness: Union[float, str] = 0.0,
    initial: Optional[PathLike] = None,
    *,
    fixed: Optional[Volume] = None,
    moving: Optional[Volume] = None,
    levels: Optional[int] = None,
    initial_field: Union[PathLike, "Field", None] = None,
) -> Warp:
    """Fits a warp on the active pairs with both points, as the command line fits it.

    Args:
        pairs: from :func:`read_landmarks`, or ``Pairs(moving, fixed)``.
        method: ``"tps"``, ``"hbspline"``, ``"affine"``, ``"similarity"`` or ``"rigid"``.
        stiffness: the TPS's λ ≥ 0 (0 interpolates), or ``"auto"``: the λ under which the pairs are most likely.
        initial: an ITK linear ``.tfm`` (affine, Euler, versor rigid, similarity, ...), an ANTs ``.mat`` or an ITK
            ``.h5`` of affines (fixed points to moving points) under the landmark warp,
            as ``warpbench align`` writes it; or FSL's FLIRT matrix, read against ``fixed`` (FLIRT's ``-ref``) and
            ``moving`` (its ``-in``), which it needs; or AFNI's ``.aff12.1D`` (``fixed`` its base, ``moving`` its
            source, neither oblique), which needs them too.
        fixed, moving: the volumes (only their grids are read). With them the pairs are checked to lie inside,
            and the fit's domains are their boxes, as on the command line; without them, the points' box grown by
            a tenth (it matters only to ``hbspline``).
        levels: the hierarchical B-spline's levels.
        initial_field: a displacement field under the landmark warp (a registration the landmarks correct): a
            file in any flavour :func:`read_field` reads, or a :class:`Field` (one :func:`read_field` returned, or
            one made from another tool's array: LPS mm, the pull-back unless its ``direction`` is ``"forward"``).
            It maps fixed points first and ``initial`` after it, as ``antsApplyTransforms -t FIELD -t TFM`` does.
            A Learn2Reg ``.npz`` needs ``fixed`` and ``moving``; its NIfTI form is read with
            ``read_field(path, fixed, moving, learn2reg=True)`` and given as that :class:`Field`. A file of ITK
            B-spline transforms is applied exactly everywhere; the :class:`Field` read from it is its samples on the
            fixed grid, and the identity outside it.
    """
    if (fixed is None) != (moving is None):
        raise ValueError("give both fixed= and moving=, or neither")
    m, f, names, active = pairs._arrays()
    native = _warpbench.Warp.fit(
        m,
        f,
        names,
        active,
        pairs.source,
        method,
        stiffness,
        levels,
        None if initial is None else os.fspath(initial),
        None if fixed is None else fixed._grid(),
        None if moving is None else moving._grid(),
        _initial_field(initial_field),
    )
    return Warp(native, pairs, fixed, moving)


def _initial_field(field: Union[PathLike, Field, None]) -> Any:
    """``fit``'s ``initial_field`` as the native fit takes it: a path, or a :class:`Field`'s arrays."""
    if field is None:
        return None
    if isinstance(field, Field):
        if field.direction not in (None, "pullback", "forward"):
            raise ValueError(f"initial_field: direction {field.direction!r}: give 'pullback', 'forward' or None")
        array = np.ascontiguousarray(field.array, dtype=np.float32)
        lps = np.ascontiguousarray(field.lps_from_index, dtype=np.float64)
        return (array, lps, field.direction == "forward")
    return os.fspath(field)


# --- The subcommands with a --json report ----------------------------------------------------------------------


def _flags(options: Dict[str, Any]) -> List[str]:
    """Keyword arguments as the CLI's flags: ``grid_mm=8`` is ``--grid-mm 8``, ``True`` a bare flag, ``False``
    and ``None`` nothing, a sequence a comma-separated list."""
    argv: List[str] = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if value is None or value is False:
            continue
        if value is True:
            argv.append(flag)
        elif isinstance(value, Field):
            raise ValueError(f"{key}: the command takes a file, not a Field: give the path it was read from")
        elif isinstance(value, (list, tuple)):
            argv += [flag, ",".join(str(v) for v in value)]
        else:
            argv += [flag, os.fspath(value) if isinstance(value, os.PathLike) else str(value)]
    return argv


class _Inputs:
    """Paths for the CLI: a path as given, a volume by its file (or a temporary NIfTI when it has none), pairs as
    a temporary BigWarp JSON file."""

    def __init__(self, stack: ExitStack) -> None:
        self._stack = stack
        self._dir: Optional[str] = None

    def _tmp(self, name: str) -> str:
        if self._dir is None:
            self._dir = self._stack.enter_context(tempfile.TemporaryDirectory(prefix="warpbench-"))
        return os.path.join(self._dir, name)

    def volume(self, v: Union[PathLike, Volume], name: str) -> str:
        if isinstance(v, Volume):
            if v.path is not None:
                return os.fspath(v.path)
            path = self._tmp(name + ".nii")
            v.write(path)
            return path
        return os.fspath(v)

    def pairs(self, p: Union[PathLike, Pairs]) -> str:
        if isinstance(p, Pairs):
            path = self._tmp("pairs.json")
            write_landmarks(path, p)
            return path
        return os.fspath(p)

    def output(self, given: Optional[PathLike], name: str) -> str:
        return os.fspath(given) if given is not None else self._tmp(name)


def run_cli(*argv: str) -> str:
    """Runs ``warpbench <argv…>`` in this process and returns what it printed (its report with ``--json``)."""
    return _warpbench.run_command([os.fspath(a) for a in argv])


def _run_json(argv: List[str], quiet: bool) -> Dict[str, Any]:
    argv = argv + ["--json"] + (["--quiet"] if quiet else [])
    return json.loads(_warpbench.run_command(argv))


def align(
    fixed: Union[PathLike, Volume],
    moving: Union[PathLike, Volume],
    affine: bool = False,
    *,
    out_tfm: Optional[PathLike] = None,
    quiet: bool = True,
    **options: Any,
) -> Dict[str, Any]:
    """Automatic initial alignment by Mattes mutual information (``warpbench align``): rigid, or ``affine``.

    Writes the result to ``out_tfm`` (an ITK ``.tfm``, or an ANTs ``.mat``) when given; the other options are the CLI's (``samples``,
    ``bins``, ``shrink``, ``seed``, ``force``). Returns the CLI's ``--json`` report (schema
    ``warpbench-align/1``), with ``moving_from_fixed`` as a 4×4 array."""
    with ExitStack() as stack:
        io = _Inputs(stack)
        argv = ["align", "--fixed", io.volume(fixed, "fixed"), "--moving", io.volume(moving, "moving")]
        argv += ["--out-tfm", io.output(out_tfm, "align.tfm")] + _flags({"affine": affine, **options})
        report = _run_json(argv, quiet)
    report["moving_from_fixed"] = np.array(report["moving_from_fixed"])
    return report


def register(
    fixed: Optional[Union[PathLike, Volume]] = None,
    moving: Optional[Union[PathLike, Volume]] = None,
    landmarks: Optional[Union[PathLike, Pairs]] = None,
    *,
    out_field: Optional[PathLike] = None,
    out: Optional[PathLike] = None,
    quiet: bool = True,
    **options: Any,
) -> Dict[str, Any]:
    """Deformable registration by intensities under the landmarks (``warpbench register``).

    The options are the CLI's: ``session``, ``initial``, ``initial_field`` (a file; ``initial_field_format`` is
    ``"learn2reg"`` for Learn2Reg's NIfTI form), ``method``, ``stiffness``, ``metric``
    (``"mi"``, ``"ngf"`` or ``"lncc"``), ``fixed_mask`` and ``moving_mask`` (paths), ``grid_mm``, ``levels``,
    ``landmark_weight``, ``bending_weight``, ``samples``, ``iterations``, ``seed``, ``backend``, ``format``,
    ``force``, ``out_inverse_field`` (a path: the inverse as a forward field on the moving grid). ``out_field``
    (the displacement field) and ``out`` (the warped volume) are written when given. With ``session``, ``fixed``
    and ``moving`` may be left out: the session's volumes are read, each with the frame or series the window read.
    Returns the CLI's ``--json`` report (schema ``warpbench-register/2``)."""
    if (fixed is None or moving is None) and options.get("session") is None:
        raise ValueError("register: give fixed and moving, or session= (whose volumes are read)")
    with ExitStack() as stack:
        io = _Inputs(stack)
        argv = ["register"]
        for name, volume in (("fixed", fixed), ("moving", moving)):
            if volume is not None:
                argv += ["--" + name, io.volume(volume, name)]
        if landmarks is not None:
            argv += ["--landmarks", io.pairs(landmarks)]
        argv += ["--out-field", io.output(out_field, "field.nii.gz")]
        if out is not None:
            argv += ["--out", os.fspath(out)]
        argv += _flags(options)
        return _run_json(argv, quiet)


def suggest(
    fixed: Union[PathLike, Volume],
    moving: Union[PathLike, Volume],
    points: Union[PathLike, Any],
    landmarks: Optional[Union[PathLike, Pairs]] = None,
    *,
    out: Optional[PathLike] = None,
    quiet: bool = True,
    **options: Any,
) -> Dict[str, Any]:
    """Suggested fixed targets for moving ``points`` (``warpbench suggest``): a point-list file, or an N×3 array
    of LPS mm. The prediction comes from ``landmarks`` (or ``session``/``initial`` in the options) and the search
    from the images. ``out`` (BigWarp CSV or JSON) is written when given; the other options are the CLI's
    (``search_radius_mm``, ``method``, ``stiffness``, ``initial``, ``initial_field`` and ``initial_field_format``,
    ``session``, ``force``).
    Returns its ``--json`` report."""
    with ExitStack() as stack:
        io = _Inputs(stack)
        argv = ["suggest", "--fixed", io.volume(fixed, "fixed"), "--moving", io.volume(moving, "moving")]
        if isinstance(points, (str, os.PathLike)):
            argv += ["--points", os.fspath(points)]
        else:
            listed = _points(points)
            path = io.output(None, "points.csv")
            with open(path, "w", encoding="utf-8") as f:
                f.write("x,y,z\n")
                for x, y, z in listed:
                    f.write(f"{float(x)!r},{float(y)!r},{float(z)!r}\n")
            argv += ["--points", path]
        if landmarks is not None:
            argv += ["--landmarks", io.pairs(landmarks)]
        argv += ["--out", io.output(out, "suggested.csv")] + _flags(options)
        return _run_json(argv, quiet)
