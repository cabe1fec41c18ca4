"""One log schema for simulated trials and rig runs (``docs/logs.md``).

A log file is CSV text: a format line and one JSON metadata line (both
``#``-prefixed), the header row, one line per tick, and after a clean end a
``#`` line with the end status. The columns, their units and kinds come from
the Rust crate ``sensaug-log`` through the binding: they are defined once.

``load_log(path)`` reads a simulated trial (``Trial.save``) and a rig log
(``sensaug-rt``) alike and returns a :class:`Log`: ``.data`` a numpy
structured array (int64 for ``tick``, ``phase``, ``drive_state``...,
float64, bool), ``.meta`` the metadata dict. A partial last line (the rig was
killed mid-write) is ignored.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from sensaug import _core

__all__ = ["COLUMNS", "DTYPE", "PHASE_NAMES", "UNITS", "UNKNOWN_INT", "Log", "from_columns", "from_records", "load_log", "to_json"]

_SCHEMA = _core.log_schema()
FORMAT_LINE: str = _SCHEMA["format_line"]
#: Column names, in file order.
COLUMNS: tuple[str, ...] = tuple(c[0] for c in _SCHEMA["columns"])
#: Unit of every column (symbols in ``meta["units"]``).
UNITS: dict[str, str] = {c[0]: c[1] for c in _SCHEMA["columns"]}
#: Names of the ``phase`` codes (index = code); -1 is outside the protocol.
PHASE_NAMES: tuple[str, ...] = tuple(_SCHEMA["phase_names"])
#: Value of an integer column that the log's source cannot know.
UNKNOWN_INT: int = _SCHEMA["unknown_int"]

_NUMPY = {"int": np.int64, "float": np.float64, "bool": np.bool_}
# Booleans are written 0/1 and parsed as small integers first.
_PARSE = {"int": np.int64, "float": np.float64, "bool": np.int8}


def _dtype(columns: list[tuple[str, str]], table: Mapping[str, Any]) -> np.dtype:
    return np.dtype([(name, table[kind]) for name, kind in columns])


#: The structured dtype of ``Log.data``.
DTYPE: np.dtype = _dtype([(c[0], c[2]) for c in _SCHEMA["columns"]], _NUMPY)


def from_columns(columns: Mapping[str, np.ndarray]) -> np.ndarray:
    """A structured array with :data:`DTYPE` from one array per column."""
    n = len(columns[COLUMNS[0]])
    data = np.empty(n, dtype=DTYPE)
    for name in COLUMNS:
        data[name] = columns[name]
    return data


def from_records(records: np.ndarray) -> np.ndarray:
    """A structured array with :data:`DTYPE` viewing ``records``, the bytes of
    packed rows in :data:`COLUMNS` order (as ``_core.run_scenario`` returns
    them): no copy."""
    if records.dtype != np.uint8 or records.ndim != 1 or records.size % DTYPE.itemsize:
        raise ValueError(
            f"records: expected 1-D uint8 bytes, a multiple of {DTYPE.itemsize} (one row of DTYPE); "
            f"got {records.dtype} with shape {records.shape}"
        )
    return records.view(DTYPE)


@dataclass(repr=False)
class Log:
    """A log: ``data`` (structured array, one record per tick) and ``meta``
    (format, source, versions, git commit, start time, configuration,
    columns with units, phase names, loop settings; ``end`` after a clean
    end)."""

    data: np.ndarray
    meta: dict

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def __len__(self) -> int:
        return len(self.data)

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(self.data.dtype.names or ())

    @property
    def units(self) -> dict[str, str]:
        """Unit of each column."""
        return {c["name"]: c["unit"] for c in self.meta.get("columns", [])} or dict(UNITS)

    @property
    def complete(self) -> bool:
        """Whether the run wrote its end-status line (absent after a crash)."""
        return "end" in self.meta

    def phase_code(self, name: str) -> int:
        """The ``phase`` column's code of a phase kind ('gains', 'trajectory', 'integration')."""
        names = list(self.meta.get("phase_names", PHASE_NAMES))
        if name not in names:
            raise ValueError(f"phase: must be one of {names}, got {name!r}")
        return names.index(name)

    def to_pandas(self):
        """A ``pandas.DataFrame`` of the columns (metadata in ``df.attrs``)."""
        try:
            import pandas as pd
        except ImportError as e:  # pragma: no cover - pandas is a test dependency
            raise ImportError("to_pandas: needs pandas (pip install pandas)") from e
        df = pd.DataFrame(self.data)
        df.attrs.update(self.meta)
        return df

    def save(self, path: str | Path) -> Path:
        """Writes this log (metadata, rows, end status) with the Rust writer."""
        meta = {k: v for k, v in self.meta.items() if k != "end"}
        end = self.meta.get("end")
        _core.write_log(
            str(path),
            self.data,
            meta_json=to_json(meta),
            end_json=None if end is None else to_json(end),
        )
        return Path(path)

    def __repr__(self) -> str:
        n = len(self.data)
        span = f", t {self.data['t'][0]:g}..{self.data['t'][-1]:g} s" if n else ""
        state = "complete" if self.complete else "no end line"
        return (
            f"<{type(self).__name__} {self.meta.get('source', '?')}: {n} ticks{span}, "
            f"{len(self.columns)} columns, {state}, started {self.meta.get('start_time_utc', '?')}>"
        )


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def to_json(obj: Any) -> str:
    """JSON text for the metadata (numpy arrays as lists; NaN is an error:
    the metadata must be strict JSON)."""
    return json.dumps(obj, default=_jsonable, allow_nan=False)


def load_log(path: str | Path) -> Log:
    """Reads a log file (simulated trial or rig run).

    Every complete line is read; a partial last line (a killed writer) is
    ignored. Raises ``ValueError`` naming the file and what is wrong when
    it is not a sensaug log, or a line does not parse.
    """
    path = Path(path)
    raw = path.read_bytes()
    end = raw.rfind(b"\n")
    lines = raw[: end + 1].decode("utf-8").split("\n")[:-1]
    if not lines or lines[0] != FORMAT_LINE:
        first = lines[0][:40] if lines else raw[:40].decode("utf-8", "replace")
        raise ValueError(f"{path}: not a sensaug log of this version (first line {first!r}, expected {FORMAT_LINE!r})")
    if len(lines) < 3 or not lines[1].startswith("# "):
        raise ValueError(f"{path}: incomplete header (the metadata line and the header row are needed)")
    try:
        meta = json.loads(lines[1][2:])
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: line 2: metadata is not valid JSON: {e}") from None
    columns = [(c["name"], c["kind"]) for c in meta["columns"]]
    header = lines[2].split(",")
    if header != [c[0] for c in columns]:
        raise ValueError(f"{path}: line 3: header row does not match the metadata's columns")
    body, trailer = [], []
    for ln in lines[3:]:
        (trailer if ln.startswith("#") else body).append(ln)
    for ln in trailer:
        try:
            meta.update(json.loads(ln[1:]))
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: end-status line is not valid JSON: {e}") from None
    dtype = _dtype(columns, _NUMPY)
    if not body:
        return Log(data=np.empty(0, dtype=dtype), meta=meta)
    try:
        parsed = np.loadtxt(io.StringIO("\n".join(body)), delimiter=",", dtype=_dtype(columns, _PARSE), ndmin=1)
    except ValueError as e:
        raise ValueError(f"{path}: a data row does not parse: {e}") from None
    return Log(data=parsed.astype(dtype), meta=meta)
