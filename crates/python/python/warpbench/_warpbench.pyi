"""Type stubs of the extension module: the Rust half of the package. Use the functions of ``warpbench`` itself."""

from typing import List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

Grid = Tuple[Sequence[int], npt.NDArray[np.float64]]

def read_volume(
    path: str, frame: Optional[int] = None, series: Optional[str] = None
) -> Tuple[np.ndarray, npt.NDArray[np.float64], str]: ...
def write_volume(
    path: str, array: np.ndarray, lps_from_index: npt.NDArray[np.float64], modality: Optional[str] = None
) -> None: ...
def read_field(
    path: str,
    pair: Optional[Tuple[Tuple[List[int], npt.NDArray[np.float64]], Tuple[List[int], npt.NDArray[np.float64]]]] = None,
    learn2reg: bool = False,
) -> Tuple[np.ndarray, npt.NDArray[np.float64], str, Optional[str]]: ...
def read_landmarks(
    path: str, fixed_path: Optional[str] = None, ras: bool = False
) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], List[str], List[bool], str]: ...
def write_landmarks(
    path: str,
    moving: npt.NDArray[np.float64],
    fixed: npt.NDArray[np.float64],
    names: List[str],
    active: List[bool],
    fixed_path: Optional[str] = None,
    format: Optional[str] = None,
    ras: bool = False,
) -> None: ...
def run_command(argv: List[str]) -> str: ...
def panic_for_test() -> None: ...

class Warp:
    @staticmethod
    def fit(
        moving: npt.NDArray[np.float64],
        fixed: npt.NDArray[np.float64],
        names: List[str],
        active: List[bool],
        origin: str,
        method: str = "tps",
        stiffness: Union[float, str, None] = None,
        levels: Optional[int] = None,
        initial: Optional[str] = None,
        fixed_grid: Optional[Grid] = None,
        moving_grid: Optional[Grid] = None,
        initial_field: Union[str, Tuple[npt.NDArray[np.float32], npt.NDArray[np.float64], bool], None] = None,
    ) -> "Warp": ...
    @property
    def method(self) -> str: ...
    @property
    def rows(self) -> List[int]: ...
    def pullback(self, points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def forward(self, points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def jacobian(self, reference: Grid, quantity: str = "det") -> npt.NDArray[np.float32]: ...
    def field(
        self,
        reference: Grid,
        direction: str = "pullback",
        path: Optional[str] = None,
        format: str = "itk",
        moving: Optional[Grid] = None,
    ) -> npt.NDArray[np.float32]: ...
    def resample(
        self,
        moving: np.ndarray,
        lps: npt.NDArray[np.float64],
        reference: Optional[Grid] = None,
        interpolation: str = "linear",
        exact: bool = False,
        grid_n: int = 64,
        float: bool = False,
        outside: Optional[float] = None,
        modality: Optional[str] = None,
        backend: str = "cpu",
    ) -> Tuple[np.ndarray, npt.NDArray[np.float64], str]: ...
    def to_itk_tfm(self, path: str) -> None: ...
    def to_fsl(self, path: str) -> None: ...
    def to_afni(self, path: str) -> None: ...
    def to_lta(self, path: str, fixed_name: str, moving_name: str) -> None: ...
    def to_xfm(self, path: str) -> None: ...
    def to_elastix(self, path: str, reference: Grid) -> None: ...
    def to_dicom(self, path: str, fixed_path: str, moving_path: str, reference: Grid) -> str: ...
    def leave_one_out(self) -> List[Tuple[int, float, Optional[float]]]: ...
    def folding(
        self, reference: Optional[Grid] = None, n: int = 64
    ) -> Tuple[float, Tuple[float, float, float], float, float, int]: ...
