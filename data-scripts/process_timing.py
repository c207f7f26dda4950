"""Timing two whole processes in turn, as the peer benchmarks under data-scripts/ do (imported, not run).

`alternate(a_cmd, b_cmd, runs)` runs each command once as a warm-up, then RUNS times each, A B A B ..., and returns
the (wall seconds, CPU seconds) of every counted run; `report(a, b)` prints the median wall and CPU seconds of each
and the median of the A/B ratios taken pair by pair. CPU seconds are the child's own (`os.wait4`). Peak memory is not
measured: a child's `ru_maxrss` starts from the forking Python's.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time


def run(cmd: list[str]) -> tuple[float, float]:
    """Wall seconds and CPU seconds of one whole process; exits naming the command if it fails."""
    start = time.monotonic()
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.monotonic() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"{cmd[0]} failed: {child.stderr.read().decode() if child.stderr else ''}")
    return wall, usage.ru_utime + usage.ru_stime


def alternate(a_cmd: list[str], b_cmd: list[str], runs: int) -> tuple[list, list]:
    """One warm-up of each, then `runs` of each in turn."""
    run(a_cmd), run(b_cmd)
    a, b = [], []
    for _ in range(runs):
        a.append(run(a_cmd))
        b.append(run(b_cmd))
    return a, b


def report(a: list, b: list) -> None:
    """Medians of each, and the median of the pair-by-pair ratios."""
    med = lambda xs, k: statistics.median(x[k] for x in xs)  # noqa: E731
    for what, k in (("wall s", 0), ("cpu s", 1)):
        ratio = statistics.median(x[k] / y[k] for x, y in zip(a, b))
        print(f"{what:9} A {med(a, k):8.3f}  B {med(b, k):8.3f}  A/B {ratio:.2f}")
