"""Shared helpers of the ``opal`` package: the result type, CSV columns, command calls."""

from __future__ import annotations

import csv
import json
from typing import Any, Callable, Dict, List, Optional

import numpy as np

from . import _native


class Result(dict):
    """A dict whose keys are also attributes (``r.alpha`` is ``r["alpha"]``).

    Holds the fields of the CLI's JSON output (e.g. fit.json, report.json) and arrays added by
    the Python API (curves, textures).
    """

    def __getattr__(self, name: str) -> Any:
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None

    def __dir__(self) -> List[str]:
        return sorted(set(super().__dir__()) | set(self.keys()))


def run_command(argv: List[str], threads: Optional[int], progress: Optional[Callable]) -> Any:
    """Runs an ``opal`` subcommand in-process (no printing) and decodes its JSON result."""
    return json.loads(_native.run_command([str(a) for a in argv], threads=threads, progress=progress))


def columns(d: Dict[str, list]) -> Dict[str, np.ndarray]:
    """JSON columns as numpy arrays (numbers → float64 / int64, text → str)."""
    out: Dict[str, np.ndarray] = {}
    for k, v in d.items():
        if v and isinstance(v[0], str):
            out[k] = np.asarray(v, dtype=str)
        elif v and all(isinstance(x, int) for x in v):
            out[k] = np.asarray(v, dtype=np.int64)
        else:
            out[k] = np.asarray(v, dtype=np.float64)
    return out


def read_csv_columns(path: str) -> Dict[str, np.ndarray]:
    """A CSV with a header row as columns (numeric columns float64, others str)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    out: Dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        col = [r[j] for r in body]
        try:
            out[name] = np.asarray([float(x) for x in col], dtype=np.float64)
        except ValueError:
            out[name] = np.asarray(col, dtype=str)
    return out
