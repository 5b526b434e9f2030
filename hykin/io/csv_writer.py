"""The one CSV writer: named columns -> a CSV file with one header line.

Numbers are written so that they read back to the same float64 (Python's shortest ``repr``, or
Arrow's shortest round-trip text on the fast path). Two styles pin the bytes of the two kinds of
CSV hykin writes (both are part of the file-format contract):

* :data:`DATASET_STYLE` (dataset files, :func:`hykin.io.dataset_files.write_dataset`): ``\\n``
  line ends, integer columns as floats (``3.0``), booleans ``True``/``False``; when every column is
  numeric and pyarrow is installed Arrow writes the rows (4-5x faster; ``1.0`` is then ``1``).
* :data:`ROWS_STYLE` (command outputs: ``hykin fk/ik/compensate/plan`` rows,
  :func:`hykin.cli.common.write_rows`): ``\\r\\n`` line ends (the csv module's default dialect),
  integers as integers, booleans ``true``/``false``.

Every other value is written as ``str(value)``; the header is quoted by the csv module's rules.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["DATASET_STYLE", "ROWS_STYLE", "CsvStyle", "format_column", "write_csv"]


@dataclass(frozen=True)
class CsvStyle:
    """How cells are spelt: line end, integers (``"int"`` or ``"float"``), booleans (true, false
    text), and whether Arrow may write an all-numeric table."""

    eol: str
    ints: str
    bools: tuple[str, str]
    arrow: bool


DATASET_STYLE = CsvStyle(eol="\n", ints="float", bools=("True", "False"), arrow=True)
ROWS_STYLE = CsvStyle(eol="\r\n", ints="int", bools=("true", "false"), arrow=False)


def _cell(v, style: CsvStyle) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (bool, np.bool_)):
        return style.bools[0] if v else style.bools[1]
    return str(v)


def format_column(values, style: CsvStyle) -> list[str]:
    """``(N,)`` values -> their CSV text in ``style`` (floats: shortest repr of the float64)."""
    a = np.asarray(values)
    k = a.dtype.kind
    if k == "f" or (k in "iu" and style.ints == "float"):
        return list(map(repr, a.astype(np.float64).tolist()))
    if k in "iu":
        return list(map(str, a.tolist()))
    if k == "b":
        t, f = style.bools
        return [t if v else f for v in a.tolist()]
    if k == "O":
        return [_cell(v, style) for v in a.tolist()]
    return list(map(str, a.tolist()))


def write_csv(path: str | Path, columns: dict, style: CsvStyle = DATASET_STYLE) -> None:
    """Write ``columns`` (name -> ``(N,)`` values, in order) to ``path`` as CSV in ``style``."""
    names = [str(k) for k in columns]
    header = _header_line(names, style.eol)
    cols = [np.asarray(v) for v in columns.values()]
    if style.arrow and cols and all(c.dtype.kind in "iuf" for c in cols):
        try:
            import pyarrow as pa
            import pyarrow.csv as pacsv
        except ImportError:  # optional dependency: Python's formatting below (same values, slower)
            pa = None
        if pa is not None:
            table = pa.table({f"c{i}": pa.array(c.astype(np.float64)) for i, c in enumerate(cols)})
            with open(path, "wb") as fh:
                fh.write(header.encode("utf-8"))
                eol = {} if style.eol == "\n" else {"eol": style.eol}  # older pyarrow: no eol option
                pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False, quoting_style="none", **eol))
            return
    text = [format_column(c, style) for c in cols]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(header)
        csv.writer(fh, lineterminator=style.eol).writerows(zip(*text))


def _header_line(names: list[str], eol: str) -> str:
    import io

    buf = io.StringIO()
    csv.writer(buf, lineterminator=eol).writerow(names)
    return buf.getvalue()
