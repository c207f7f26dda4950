"""Cohorts on Dask: one case, one task.

A cohort is a table of cases. Each case names its fixed and moving volumes, its landmarks and its outputs. Every
case runs as one Dask task on any ``dask.distributed`` cluster: a ``LocalCluster`` out of the box, or Slurm through
``dask-jobqueue`` (docs/python.md). A failed case fails alone, with its error recorded. Every output is written
atomically, and the case's report (``<out>.report.json``) last, so a rerun skips each case whose report is there.

>>> from warpbench.batch import Case, run_cohort
>>> cases = [Case("s01", "s01_ct.nii.gz", "s01_mr.nii.gz", "s01.csv", out="out/s01_mr_in_ct.nii.gz")]
>>> results = run_cohort(cases)           # a LocalCluster of 2 workers
>>> [(r.name, r.status, r.leave_one_out_mm) for r in results]
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterable, List, Optional, Sequence, Union

PathLike = Union[str, "os.PathLike[str]"]

REPORT_SCHEMA = "warpbench-case/1"


@dataclass
class Case:
    """One subject pair.

    Attributes:
        name: the case's name in the results.
        fixed, moving: the volumes (any format warpbench reads).
        landmarks: landmark pairs (BigWarp CSV or JSON, a plain CSV, a session).
        out: the moving volume resampled onto the fixed grid (``.nii``, ``.nii.gz``, ``.nrrd``, ``.mha``, ``.mgz``, ``.mnc``,
            ``.ome.zarr``).
        out_field: the pull-back as an ITK displacement field (optional).
        out_tfm: the pull-back as an ITK transform file (optional).
        method, stiffness, initial, initial_field: as :func:`warpbench.fit` (``initial_field``: another tool's
            registration of the pair, which the landmarks correct).
        register: refine the landmark warp by intensities (:func:`warpbench.register`) before writing.
        fixed_frame, moving_frame: the frame to read of a 4-D fixed or moving file (from 0).
        fixed_series, moving_series: the series to read of a DICOM folder of several, by its SeriesInstanceUID.
    """

    name: str
    fixed: PathLike
    moving: PathLike
    landmarks: PathLike
    out: PathLike
    out_field: Optional[PathLike] = None
    out_tfm: Optional[PathLike] = None
    method: str = "tps"
    stiffness: Union[float, str] = 0.0
    initial: Optional[PathLike] = None
    initial_field: Optional[PathLike] = None
    register: bool = False
    options: Dict[str, Any] = field(default_factory=dict)
    fixed_frame: Optional[int] = None
    moving_frame: Optional[int] = None
    fixed_series: Optional[str] = None
    moving_series: Optional[str] = None

    def parts(self) -> Dict[str, Any]:
        """The frame and series choices that were made, by the command line's option names."""
        chosen = {
            "fixed_frame": self.fixed_frame,
            "moving_frame": self.moving_frame,
            "fixed_series": self.fixed_series,
            "moving_series": self.moving_series,
        }
        return {k: v for k, v in chosen.items() if v is not None}

    @property
    def report_path(self) -> Path:
        """Where the case's report goes: beside ``out``, written last."""
        return Path(os.fspath(self.out) + ".report.json")

    def outputs(self) -> List[Path]:
        return [Path(os.fspath(p)) for p in (self.out, self.out_field, self.out_tfm) if p is not None]


@dataclass
class CaseResult:
    """What happened to one case: ``status`` is ``"ok"``, ``"failed"`` (with ``error``) or ``"skipped"`` (its
    outputs were complete; the numbers are the earlier run's)."""

    name: str
    status: str
    seconds: float = 0.0
    error: Optional[str] = None
    method: Optional[str] = None
    pairs: Optional[int] = None
    leave_one_out_mm: Optional[float] = None
    leave_one_out_max_mm: Optional[float] = None
    min_det: Optional[float] = None
    registration: Optional[Dict[str, Any]] = None
    outputs: List[str] = field(default_factory=list)
    worker: Optional[str] = None


def _write_json_atomic(path: Path, value: Dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".warpbench-partial-", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(value, f, indent=2)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def complete(case: Case) -> bool:
    """Whether the case's outputs are all there. Each output is written atomically and the report last, so a report
    means every output before it is whole."""
    return case.report_path.is_file() and all(p.is_file() for p in case.outputs())


def run_case(case: Case, *, overwrite: bool = False) -> CaseResult:
    """Runs one case in this process: reads, fits, checks (leave-one-out, folding), optionally registers, writes.
    Never raises for a bad case: the error is in the result."""
    import warpbench as wb

    start = time.perf_counter()
    worker = _worker_name()
    if not overwrite and complete(case):
        try:
            earlier = json.loads(case.report_path.read_text(encoding="utf-8"))
            result = CaseResult(**earlier["result"])
            result.status, result.worker = "skipped", worker
            return result
        except (OSError, ValueError, KeyError, TypeError):
            pass  # an unreadable report: run the case again
    try:
        fixed = wb.read_volume(case.fixed, frame=case.fixed_frame, series=case.fixed_series)
        moving = wb.read_volume(case.moving, frame=case.moving_frame, series=case.moving_series)
        pairs = wb.read_landmarks(case.landmarks)
        warp = wb.fit(
            pairs,
            case.method,
            case.stiffness,
            case.initial,
            fixed=fixed,
            moving=moving,
            initial_field=case.initial_field,
        )
        loo = warp.leave_one_out()
        folding = warp.folding(fixed, n=32)
        registration = None
        for p in case.outputs():
            p.parent.mkdir(parents=True, exist_ok=True)
        if case.register:
            options = {
                "method": case.method,
                "stiffness": case.stiffness,
                "initial": case.initial,
                "initial_field": case.initial_field,
                "force": True,
                **case.parts(),
            }
            options.update(case.options)
            registration = wb.register(
                case.fixed, case.moving, case.landmarks, out_field=case.out_field, out=case.out, **options
            )
        else:
            warp.resample(moving).write(case.out)
            if case.out_field is not None:
                warp.field(fixed, path=case.out_field)
        if case.out_tfm is not None:
            warp.to_itk_tfm(case.out_tfm)
        result = CaseResult(
            name=case.name,
            status="ok",
            seconds=time.perf_counter() - start,
            method=warp.method,
            pairs=len(warp.rows),
            leave_one_out_mm=loo["mean_mm"],
            leave_one_out_max_mm=loo["max_mm"],
            min_det=(registration or {}).get("jacobian", {}).get("min_det", folding["min_det"]),
            registration=None
            if registration is None
            else {k: registration[k] for k in ("levels", "residuals") if k in registration},
            outputs=[str(p) for p in case.outputs()],
            worker=worker,
        )
        _write_json_atomic(case.report_path, {"schema": REPORT_SCHEMA, "result": asdict(result)})
        return result
    except Exception as e:  # noqa: BLE001 - a case fails alone, with its error recorded
        return CaseResult(
            name=case.name,
            status="failed",
            seconds=time.perf_counter() - start,
            error=f"{type(e).__name__}: {e}",
            worker=worker,
        )


def _worker_name() -> Optional[str]:
    try:
        from dask.distributed import get_worker

        return get_worker().name if get_worker() is not None else None
    except (ImportError, ValueError):
        return None


def run_cohort(
    cases: Sequence[Case],
    *,
    client: Any = None,
    overwrite: bool = False,
    table: Optional[PathLike] = None,
) -> List[CaseResult]:
    """Runs every case as one Dask task and returns their results in the cases' order.

    Args:
        cases: the cohort.
        client: a ``dask.distributed.Client``; by default a ``LocalCluster`` of 2 single-threaded worker processes,
            closed afterwards.
        overwrite: run cases whose outputs are complete too (by default they are skipped).
        table: also write the results as CSV here.
    """
    from dask.distributed import Client, LocalCluster

    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        raise ValueError("each case needs a name of its own")
    own = None
    if client is None:
        own = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(own)
    try:
        futures = client.map(run_case, list(cases), overwrite=overwrite, pure=False, key=[f"case-{n}" for n in names])
        results: List[CaseResult] = []
        for case, future in zip(cases, futures):
            try:
                results.append(future.result())
            except Exception as e:  # noqa: BLE001 - a worker that died fails its case alone
                results.append(CaseResult(name=case.name, status="failed", error=f"{type(e).__name__}: {e}"))
    finally:
        if own is not None:
            client.close()
            own.close()
    if table is not None:
        write_table(table, results)
    return results


TABLE_COLUMNS = [
    "name",
    "status",
    "seconds",
    "method",
    "pairs",
    "leave_one_out_mm",
    "leave_one_out_max_mm",
    "min_det",
    "error",
    "worker",
]


def write_table(path: PathLike, results: Iterable[CaseResult]) -> None:
    """The results as CSV, one row per case."""
    rows = [{k: asdict(r)[k] for k in TABLE_COLUMNS} for r in results]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=TABLE_COLUMNS)
        w.writeheader()
        w.writerows(rows)


def format_table(results: Iterable[CaseResult]) -> str:
    """The results as a Markdown table (what docs/python.md shows)."""
    lines = ["| case | status | s | method | pairs | LOO mean (mm) | min det | error |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        loo = "" if r.leave_one_out_mm is None else f"{r.leave_one_out_mm:.2f}"
        det = "" if r.min_det is None else f"{r.min_det:.2f}"
        lines.append(
            f"| {r.name} | {r.status} | {r.seconds:.2f} | {r.method or ''} | {r.pairs or ''} | {loo} | {det} | "
            f"{r.error or ''} |"
        )
    return "\n".join(lines)
