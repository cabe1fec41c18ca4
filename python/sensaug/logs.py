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

Every line of a format-2 log carries a chained CRC-32 (``docs/logs.md``,
"Checksums"); ``load_log`` verifies each with :func:`zlib.crc32`, an
implementation independent of the Rust writer's, and raises ``ValueError``
naming the file and the line at the first that fails. A format-1 log (no
checksums) still loads, with an :class:`UnverifiedLogWarning` and
``log.verified`` False.

The compact option: ``save("trial.parquet")`` writes the same columns and
metadata as Apache Parquet (pyarrow, zstd; ``pip install "sensaug[parquet]"``),
about a fifth of the CSV's size, and ``load_log`` reads it back bit for bit.
Parquet's page checksums (CRC-32) are written and verified on reading.
The CSV stays the rig's record: it is written line by line and survives a
crash; a Parquet file is written whole, after the trial.
"""

from __future__ import annotations

import io
import json
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from sensaug import _core

if TYPE_CHECKING:
    import pandas

__all__ = [
    "PARQUET_SUFFIX", "COLUMNS", "DTYPE", "PHASE_NAMES", "SOURCES", "UNITS", "UNKNOWN_INT",
    "Log", "UnverifiedLogWarning", "from_columns", "from_records", "load_log", "to_json", "to_records",
]  # fmt: skip

_SCHEMA = _core.log_schema()
FORMAT_LINE: str = _SCHEMA["format_line"]
#: Column names, in file order.
COLUMNS: tuple[str, ...] = tuple(c[0] for c in _SCHEMA["columns"])
#: Who fills every column: ``time``, ``controller`` (what a replay
#: recomputes), ``world`` (handle, measurement, targets, partner) or ``rig``.
SOURCES: dict[str, str] = dict(_SCHEMA["sources"])
#: Unit of every column (symbols in ``meta["units"]``).
UNITS: dict[str, str] = {c[0]: c[1] for c in _SCHEMA["columns"]}
#: Names of the ``phase`` codes (index = code); -1 is outside the protocol.
PHASE_NAMES: tuple[str, ...] = tuple(_SCHEMA["phase_names"])
#: Value of an integer column that the log's source cannot know.
UNKNOWN_INT: int = _SCHEMA["unknown_int"]
#: The header name of every row's last field, its checksum.
CHECKSUM_FIELD: str = _SCHEMA["checksum_field"]
#: How a ``#`` JSON line ends before its checksum (``,"crc32":``).
JSON_CHECKSUM_KEY: str = _SCHEMA["json_checksum_key"]
#: The first line of a format-1 log (before checksums): read, unverified.
FORMAT_LINE_V1 = "# sensaug-log 1"


class UnverifiedLogWarning(UserWarning):
    """A log whose integrity cannot be checked: a format-1 log (written
    before the checksums), or one read with ``verify=False``."""

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


def to_records(data: Mapping[str, np.ndarray] | np.ndarray) -> np.ndarray:
    """The bytes of packed records (what ``_core.write_log`` takes) from
    ``data[name]`` for every column: a structured array or a dict of 1-D
    arrays with the schema's dtypes. A missing column, another dtype or
    another length is refused naming the column."""
    kinds = {c[0]: c[2] for c in _SCHEMA["columns"]}
    for name in COLUMNS:
        try:
            column = np.asarray(data[name])
        except (KeyError, ValueError):
            raise ValueError(f"data.{name}: missing column") from None
        if column.ndim != 1 or column.dtype != DTYPE[name]:
            raise ValueError(f"data.{name}: expected a 1-D {DTYPE[name]} array (column kind {kinds[name]})")
        if len(column) != len(data[COLUMNS[0]]):
            raise ValueError(f"data.{name}: {len(column)} values, but {COLUMNS[0]} has {len(data[COLUMNS[0]])}")
    return np.ascontiguousarray(from_columns(data)).view(np.uint8)


def from_records(records: np.ndarray) -> np.ndarray:
    """A structured array with :data:`DTYPE` viewing ``records``, the bytes of
    packed rows in :data:`COLUMNS` order (as ``_core.run_scenario`` and
    ``_core.replay_robot`` return them): no copy."""
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
    meta: dict[str, Any]
    #: Every line's checksum was verified when the file was read (False for
    #: a format-1 log or ``load_log(..., verify=False)``); True for a log
    #: made in memory (a simulated trial).
    verified: bool = True

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def __len__(self) -> int:
        return len(self.data)

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(self.data.dtype.names or ())

    @property
    def units(self) -> dict[str, str]:
        """Physical unit of each column (``deg``, ``deg/s``, ``N m/rad``...),
        from the configuration's ``rig.position_unit`` (``sensaug.units``);
        ``model_units`` has the schema's symbols (``pos``, ``trq``)."""
        from sensaug.units import physical, position_unit

        unit = position_unit(self.meta.get("config"))
        return {name: physical(symbol, unit) for name, symbol in self.model_units.items()}

    @property
    def model_units(self) -> dict[str, str]:
        """Each column's unit as the log schema writes it (``pos``, ``trq``, ...)."""
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

    def to_pandas(self) -> pandas.DataFrame:
        """A ``pandas.DataFrame`` of the columns (metadata in ``df.attrs``)."""
        try:
            import pandas as pd
        except ImportError as e:  # pragma: no cover - pandas is a test dependency
            raise ImportError("to_pandas: needs pandas (pip install pandas)") from e
        df = pd.DataFrame(self.data)
        df.attrs.update(self.meta)
        return df

    def save(self, path: str | Path) -> Path:
        """Writes this log (metadata, rows, end status) with the Rust writer,
        with fresh checksums. A log that was not verified when read keeps
        saying so: its metadata gets ``"unverified_source": true`` and
        ``load_log`` reads it back unverified, with a warning. A path ending
        in ``.parquet`` writes the compact Parquet file instead (same
        columns, types and metadata)."""
        if Path(path).suffix == PARQUET_SUFFIX:
            return _save_parquet(self, Path(path))
        meta = {k: v for k, v in self.meta.items() if k != "end"}
        if not self.verified:
            meta["unverified_source"] = True
        end = self.meta.get("end")
        _core.write_log(
            str(path),
            to_records(self.data),
            meta_json=to_json(meta),
            end_json=None if end is None else to_json(end),
        )
        return Path(path)

    def __repr__(self) -> str:
        n = len(self.data)
        span = f", t {self.data['t'][0]:g}..{self.data['t'][-1]:g} s" if n else ""
        state = "complete" if self.complete else "no end line"
        if not self.verified:
            state += ", UNVERIFIED"
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


class _Corrupt(Exception):
    """A problem at one line of the file (1-based), turned into a ValueError."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(message)
        self.line = line


def _checked_json_line(n: int, line: str, crc: int, *, edited_ok: bool = False) -> tuple[dict, int, bool]:
    """A ``#`` JSON line of a format-2 log: its object (without the
    checksum), the running checksum after it, and whether the line was
    edited. ``edited_ok``: a mismatch is accepted and the line's written
    checksum carried on, so the lines after it are still verified against
    what the writer wrote."""
    at = line.rfind(JSON_CHECKSUM_KEY)
    if at < 0 or not line.endswith("}"):
        raise _Corrupt(n, f"no checksum ({JSON_CHECKSUM_KEY}N}} at its end)")
    written = line[at + len(JSON_CHECKSUM_KEY) : -1]
    edited = False
    try:
        crc = _check_crc(n, line[:at], written, crc)
    except _Corrupt:
        if not (edited_ok and written.isascii() and written.isdigit() and int(written) < 2**32):
            raise
        crc, edited = int(written), True
    if not line.startswith("# "):
        raise _Corrupt(n, "a '#' line must start with '# '")
    return _json_object(n, line[2:at] + "}"), crc, edited


def _check_crc(n: int, checked: str, written: str, crc: int) -> int:
    crc = zlib.crc32(checked.encode(), crc)
    if not (written.isascii() and written.isdigit()) or int(written) != crc:
        raise _Corrupt(
            n,
            f"checksum mismatch (written {written[:12]!r}, the bytes give {crc}): this line, or the line "
            "before it, changed after it was written (corrupted, edited, deleted or reordered lines)",
        )
    return crc


def _json_object(n: int, text: str) -> dict:
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        raise _Corrupt(n, f"not valid JSON ({e})") from None
    if not isinstance(obj, dict):
        raise _Corrupt(n, f"expected a JSON object, got {type(obj).__name__}")
    return obj


def _columns(meta: dict) -> list[tuple[str, str]]:
    """The metadata's columns as ``(name, kind)``, checked."""
    cols = meta.get("columns")
    if not isinstance(cols, list) or not cols:
        raise _Corrupt(2, "the metadata has no 'columns' list")
    out = []
    for c in cols:
        if not (isinstance(c, dict) and isinstance(c.get("name"), str) and c.get("kind") in _NUMPY):
            raise _Corrupt(2, f"metadata column {c!r} needs a name and a kind (int, float or bool)")
        out.append((c["name"], c["kind"]))
    if len({name for name, _ in out}) != len(out):
        raise _Corrupt(2, "the metadata's column names repeat")
    return out


def _parse_rows(body: list[str], first_line: int, columns: list[tuple[str, str]]) -> np.ndarray:
    """The rows' values as a structured array; a row that does not parse is
    named by its line (``first_line`` is the line of ``body[0]``)."""
    try:
        return np.loadtxt(
            io.StringIO("\n".join(body)), delimiter=",", comments=None, dtype=_dtype(columns, _PARSE), ndmin=1
        )
    except ValueError as e:
        reason = str(e)
    cast = {"int": int, "float": float, "bool": lambda v: {"0": 0, "1": 1}[v]}
    for k, row in enumerate(body):
        fields = row.split(",")
        if len(fields) != len(columns):
            raise _Corrupt(first_line + k, f"{len(fields)} values, expected {len(columns)} (the header's columns)")
        for value, (name, kind) in zip(fields, columns):
            try:
                cast[kind](value)
            except (ValueError, KeyError):
                raise _Corrupt(first_line + k, f"column {name}: {value[:40]!r} is not a valid {kind}") from None
    raise _Corrupt(first_line, f"the rows do not parse ({reason})")


def _read(raw: bytes, verify: bool, edited_metadata_ok: bool) -> Log:
    # A partial last line (no newline: a killed writer) is ignored.
    kept = raw[: raw.rfind(b"\n") + 1]
    try:
        text = kept.decode("utf-8")
    except UnicodeDecodeError as e:
        raise _Corrupt(kept.count(b"\n", 0, e.start) + 1, f"not UTF-8 text (byte {e.start} of the file)") from None
    lines = text.split("\n")[:-1]
    if not lines or lines[0] not in (FORMAT_LINE, FORMAT_LINE_V1):
        first = lines[0][:40] if lines else raw[:40].decode("utf-8", "replace")
        raise _Corrupt(1, f"not a sensaug log of a known version (first line {first!r}, expected {FORMAT_LINE!r})")
    v2 = lines[0] == FORMAT_LINE
    checked = verify and v2
    if len(lines) < 3 or not lines[1].startswith("# "):
        raise _Corrupt(len(lines) + 1, "incomplete header (the metadata line and the header row are needed)")
    crc, meta_edited = 0, False
    if checked:
        try:
            meta, crc, meta_edited = _checked_json_line(2, lines[1], crc, edited_ok=edited_metadata_ok)
        except _Corrupt as e:
            raise _Corrupt(
                2,
                f"{e}. If the metadata was edited on purpose, load_log(path, edited_metadata_ok=True) "
                "reads it (the rows still verified), and replay(..., allow_edited_config=True) replays it",
            ) from None
    else:
        meta = _json_line_unchecked(2, lines[1]) if v2 else _json_object(2, lines[1][2:])
    columns = _columns(meta)
    names = [name for name, _ in columns]
    if lines[2].split(",") != (names + [CHECKSUM_FIELD] if v2 else names):
        raise _Corrupt(3, "the header row does not match the metadata's columns")
    body: list[str] = []
    end: dict | None = None
    end_line = 0
    for n, line in enumerate(lines[3:], start=4):
        if end is not None:
            raise _Corrupt(n, "a line after the end-status line")
        if line.startswith("#"):
            if checked:
                obj, crc, _ = _checked_json_line(n, line, crc)
            else:
                obj = _json_line_unchecked(n, line) if v2 else _json_object(n, line[1:])
            if not isinstance(obj.get("end"), dict):
                raise _Corrupt(n, "a '#' line after the header must be the end status ({\"end\": {...}})")
            end = obj["end"]
            end_line = n
        elif v2:
            values, _, written = line.rpartition(",")
            if checked:
                crc = _check_crc(n, values, written, crc)
            body.append(values)
        else:
            body.append(line)
    if end is not None:
        meta["end"] = end
    dtype = _dtype(columns, _NUMPY)
    if not body:
        data = np.empty(0, dtype=dtype)
    else:
        parsed = _parse_rows(body, 4, columns)
        for name, kind in columns:
            bad = np.flatnonzero((parsed[name] != 0) & (parsed[name] != 1)) if kind == "bool" else ()
            if len(bad):
                k = int(bad[0])
                raise _Corrupt(4 + k, f"column {name}: {int(parsed[name][k])} is not a boolean (0 or 1)")
        data = parsed.astype(dtype)
    # The end status counts the rows: one more check, and the only one a
    # format-1 log has against lost rows.
    counted = (end or {}).get({"rig": "records_written", "simulation": "ticks"}.get(meta.get("source"), ""))
    if isinstance(counted, int) and counted != len(data):
        raise _Corrupt(end_line, f"the end status counts {counted} rows, the file has {len(data)}")
    if meta_edited:
        meta["metadata_edited"] = True
    data = _with_added_columns(data)
    if data.dtype == DTYPE and len(columns) != len(COLUMNS):
        # Upgraded: the metadata describes today's columns, so saving it
        # again writes a consistent header.
        meta["columns"] = [dict(zip(("name", "unit", "kind", "description"), c)) for c in _SCHEMA["columns"]]
    return Log(data=data, meta=meta, verified=checked and not meta_edited and not meta.get("unverified_source"))


#: Columns added to the schema after logs were written without them, and the
#: value such a log means by their absence: the partner-delay columns (issue
#: 24) are NaN, the paper's model (no delay assumed); the friction
#: compensation (issue 21) NaN, none recorded.
ADDED_COLUMNS: dict[str, float] = {
    "partner_delay_visual_ms": np.nan,
    "partner_delay_proprioceptive_ms": np.nan,
    "partner_delay_margin_nats": np.nan,
    "friction_nm": np.nan,
}


def _with_added_columns(data: np.ndarray) -> np.ndarray:
    """A log written before :data:`ADDED_COLUMNS` existed, in today's schema
    (those columns at their meaning-of-absence); any other log unchanged."""
    names = data.dtype.names or ()
    missing = [c for c in COLUMNS if c not in names]
    if not missing or any(c not in ADDED_COLUMNS for c in missing) or [c for c in COLUMNS if c in names] != list(names):
        return data
    out = np.empty(len(data), dtype=DTYPE)
    for c in names:
        out[c] = data[c]
    for c in missing:
        out[c] = ADDED_COLUMNS[c]
    return out


def _json_line_unchecked(n: int, line: str) -> dict:
    """A format-2 ``#`` JSON line read without checking its checksum."""
    at = line.rfind(JSON_CHECKSUM_KEY)
    return _json_object(n, line[2:at] + "}" if at >= 0 else line[1:])


#: The file suffix of the compact (Parquet) log.
PARQUET_SUFFIX = ".parquet"
#: The Parquet schema-metadata key holding the log's metadata (JSON).
_PARQUET_META_KEY = b"sensaug.meta"
_PARQUET_MAGIC = b"PAR1"


def _pyarrow():
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise ImportError(
            "Parquet logs need pyarrow: pip install pyarrow (or \"sensaug[parquet]\"); or save as .csv"
        ) from None
    return pyarrow


def _save_parquet(log: Log, path: Path) -> Path:
    pa = _pyarrow()
    meta = dict(log.meta, **({} if log.verified else {"unverified_source": True}))
    table = pa.table({name: log.data[name] for name in log.columns})
    table = table.replace_schema_metadata({_PARQUET_META_KEY: to_json(meta).encode()})
    # Byte-stream split lays each float's bytes out by significance, which
    # zstd compresses far better than the values themselves (60 s Hi5 trial:
    # 5.7 MB against 9.3 MB with dictionaries; the CSV is 30 MB).
    floats = [name for name in log.columns if log.data.dtype[name] == np.float64]
    pa.parquet.write_table(
        table, path, compression="zstd", use_dictionary=False, use_byte_stream_split=floats, write_page_checksum=True
    )
    return path


def _load_parquet(path: Path) -> Log:
    pa = _pyarrow()
    try:
        table = pa.parquet.read_table(path, page_checksum_verification=True)
    except (OSError, pa.ArrowException) as e:
        raise ValueError(f"{path}: not a readable Parquet file ({e})") from None
    raw = (table.schema.metadata or {}).get(_PARQUET_META_KEY)
    if raw is None:
        raise ValueError(f"{path}: a Parquet file without sensaug's metadata; not a sensaug log")
    meta = json.loads(raw)
    columns = [(c["name"], c["kind"]) for c in meta["columns"]]
    if table.column_names != [c[0] for c in columns]:
        raise ValueError(f"{path}: its columns do not match the metadata's")
    data = np.empty(table.num_rows, dtype=_dtype(columns, _NUMPY))
    for name, _ in columns:
        data[name] = table.column(name).to_numpy()
    return Log(data=data, meta=meta, verified=not meta.get("unverified_source"))


def load_log(path: str | Path, *, verify: bool = True, edited_metadata_ok: bool = False) -> Log:
    """Reads a log file (simulated trial or rig run): the CSV, or the
    compact Parquet (``Log.save("x.parquet")``), told apart by their first
    bytes.

    Every complete line is read; a partial last line (a killed writer) is
    ignored. Each line's checksum is verified (format 2, ``docs/logs.md``),
    so a changed, deleted, duplicated or reordered line is refused. A log cut
    at a line boundary (a crash) loads as the rows before the cut, with no
    end status (``log.complete`` False).

    Args:
        path: the log file.
        verify: False reads a damaged file without its checksums (to salvage
            what parses); the log is marked ``verified = False`` and an
            :class:`UnverifiedLogWarning` is issued.
        edited_metadata_ok: True accepts a metadata line changed after the
            run (its checksum fails) while still verifying every row
            against the writer's checksums; ``meta["metadata_edited"]`` is
            True, ``verified`` False, and a warning is issued.

    Raises:
        ValueError: ``<path>: line N: what``, at the first line that is not
            a sensaug log's, fails its checksum or does not parse.
        OSError: the file cannot be read.
    """
    path = Path(path)
    with path.open("rb") as f:
        parquet = f.read(4) == _PARQUET_MAGIC
    raw = b""
    if parquet:
        log = _load_parquet(path)
    else:
        raw = path.read_bytes()
        try:
            log = _read(raw, verify, edited_metadata_ok)
        except _Corrupt as e:
            raise ValueError(f"{path}: line {e.line}: {e}") from None
    if not log.verified:
        if raw.startswith(FORMAT_LINE_V1.encode() + b"\n"):
            why = f"a format-1 log ({FORMAT_LINE_V1!r}), written before checksums; a changed or lost row cannot be detected"
        elif log.meta.get("metadata_edited"):
            why = "its metadata line was changed after the run (checksum mismatch); the rows are verified"
        elif log.meta.get("unverified_source") and verify:
            why = "saved from a log that was not verified when read (meta['unverified_source'])"
        else:
            why = "read with verify=False; a changed or lost row cannot be detected"
        warnings.warn(
            f"{path}: UNVERIFIED: {why}",
            UnverifiedLogWarning,
            stacklevel=2,
        )
    return log
