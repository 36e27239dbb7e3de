r"""Exact text of database values for ``eha query --format json|csv`` and ``eha export``
(issue 62): every value written as DuckDB returns it to Python, never through a pandas frame
(which rounds JSON floats to 10 decimals, turns NaN and inf into ``null`` and an integer column
with a NULL into floats).

* a float: its shortest round-trip text (``repr``: ``1.4e-13``, ``0.1``), read back bit for
  bit; NaN and the infinities as the strings ``"NaN"``, ``"Infinity"``, ``"-Infinity"`` in
  JSON (JSON has no such numbers; the strings of protobuf's JSON mapping), and as ``nan``,
  ``inf``, ``-inf`` in CSV (what DuckDB, pandas and numpy read back);
* an integer of any size (HUGEINT, UBIGINT) and a DECIMAL: every digit;
* a BLOB: in JSON its bytes in lowercase hex (``"00ff61"``); in CSV DuckDB's own text of it
  (``\x00\xFFa``: printable ASCII as is, other bytes and ``"'\`` escaped), which DuckDB reads
  back as the same bytes; a UUID, a date or time: text (ISO 8601);
* a LIST or an ARRAY, a STRUCT or a MAP: a JSON array or object of the same (in CSV, that JSON);
* NULL: ``null`` in JSON, an empty field in CSV.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from decimal import Decimal
from itertools import islice
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

#: JSON text of the non-finite floats.
NON_FINITE_JSON = {"nan": '"NaN"', "inf": '"Infinity"', "-inf": '"-Infinity"'}


def _float_json(v: float) -> str:
    if math.isfinite(v):
        return repr(float(v))
    return NON_FINITE_JSON[repr(float(v))]


def json_value(v: Any) -> str:
    """JSON text of one value (see the module's notes)."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(int(v))
    if isinstance(v, float):
        return _float_json(v)
    if isinstance(v, Decimal):
        return str(v) if v.is_finite() else NON_FINITE_JSON.get(str(v).lower(), '"NaN"')
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (bytes, bytearray, memoryview)):
        return f'"{bytes(v).hex()}"'
    if isinstance(v, dict):
        return "{" + ",".join(f"{json.dumps(str(k), ensure_ascii=False)}:{json_value(x)}"
                              for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(json_value(x) for x in v) + "]"
    if isinstance(v, (_dt.datetime, _dt.date, _dt.time)):
        return f'"{v.isoformat()}"'
    if hasattr(v, "item") and callable(v.item):  # a numpy scalar
        return json_value(v.item())
    return json.dumps(str(v), ensure_ascii=False)   # UUID, timedelta, ...


def csv_value(v: Any) -> str | None:
    """CSV field of one value, before quoting (``None`` for NULL: an empty field)."""
    if v is None:
        return None
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)  # nan, inf, -inf, or the shortest round-trip text
    if isinstance(v, (int, Decimal, str)):
        return str(v)
    if isinstance(v, (bytes, bytearray, memoryview)):
        return "".join(chr(c) if 32 <= c <= 126 and c not in b"\"'\\" else f"\\x{c:02X}"
                       for c in bytes(v))
    if isinstance(v, (dict, list, tuple)):
        return json_value(v)
    if isinstance(v, (_dt.datetime, _dt.date, _dt.time)):
        return v.isoformat()
    return str(v)


#: Rows encoded at a time: a batch is turned into columns, each column encoded by one C-level
#: ``map`` (a float column by ``float.__repr__``), then joined row by row.
BATCH = 10_000


def _batches(rows: Iterable[Sequence[Any]]) -> Iterator[list]:
    it = iter(rows)
    while batch := list(islice(it, BATCH)):
        yield batch


def _column_text(col: tuple, one: Callable[[Any], str | None], non_finite: Mapping[str, str]
                 ) -> list:
    """The text of each value of one column: a column of floats by ``float.__repr__`` (its
    non-finite values, if its sum says there are any, through ``non_finite``), any other
    column value by value (``one``)."""
    if all(type(v) is float for v in col):
        out = list(map(float.__repr__, col))
        if not math.isfinite(sum(col)):   # a NaN or an infinity (or a sum that overflowed)
            out = [non_finite.get(x, x) for x in out]
        return out
    return list(map(one, col))


def json_records(columns: Sequence[str], rows: Iterable[Sequence[Any]]) -> Iterator[str]:
    """The JSON text of a list of records (one object per row), in pieces: ``[``, the
    records separated by ``,``, then ``]``."""
    from operator import add

    keys = [json.dumps(str(c), ensure_ascii=False) + ":" for c in columns]
    nan_text = {"nan": NON_FINITE_JSON["nan"], "inf": NON_FINITE_JSON["inf"],
                "-inf": NON_FINITE_JSON["-inf"]}
    yield "["
    first = True
    for batch in _batches(rows):
        cols = [_column_text(c, json_value, nan_text) for c in zip(*batch)]
        text = ",".join(["{" + ",".join(map(add, keys, row)) + "}" for row in zip(*cols)])
        yield ("" if first else ",") + text
        first = False
    yield "]"


def csv_lines(columns: Sequence[str], rows: Iterable[Sequence[Any]]) -> Iterator[str]:
    """The CSV text (header, then the rows) in pieces, RFC 4180 quoting."""
    import csv
    import io

    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    yield buf.getvalue()

    def one(v: Any) -> str:
        x = csv_value(v)
        return "" if x is None else x

    for batch in _batches(rows):
        buf.seek(0)
        buf.truncate()
        writer.writerows(zip(*[_column_text(c, one, {}) for c in zip(*batch)]))
        yield buf.getvalue()


__all__ = ["json_value", "csv_value", "json_records", "csv_lines", "NON_FINITE_JSON"]
