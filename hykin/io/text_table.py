"""The one reader of delimited text tables (CSV, ``;``/tab/whitespace separated), and its columns.

:func:`read_delimited` reads a file into a :class:`TextTable` (header, cells as text, the file line
of every data row); :func:`float_column` and :func:`lenient_column` turn a column into numbers.
Every reader of text files in hykin goes through them: dataset files
(:mod:`hykin.io.dataset_files`), the fixed-layout importers (:mod:`hykin.measure.importers`) and the
generic table importer (:mod:`hykin.measure.table_import`, which adds the layout of a
:class:`~hykin.measure.table_map.TableMap`).

Every error is a :class:`~hykin.io.dataset.DatasetError` naming the file, the data row (1-based,
the first row under the header is row 1) with its line in the file, and the column.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .dataset import DatasetError

__all__ = ["TextTable", "delimiter_name", "detect_delimiter", "float_column", "group_names", "lenient_column", "read_delimited", "read_lines",
           "split_lines", "with_file_line"]

_DELIMITER_NAMES = {",": "','", ";": "';'", "\t": "tab", " ": "whitespace", "|": "'|'"}


@dataclass
class TextTable:
    """A delimited text table: ``header``, ``rows`` (cells as text, stripped), ``lines`` ``(N,)``
    1-based file line of each row, the ``delimiter`` used and the file name ``where``."""

    where: str
    header: list[str]
    rows: list[list[str]]
    lines: np.ndarray
    delimiter: str
    group_lines: list[int] = field(default_factory=list)

    def col(self, name: str) -> list[str]:
        """The cells of column ``name`` (text), one per row."""
        i = self.header.index(name)
        return [r[i] for r in self.rows]

    def error(self, row: int | None, column: str | None, msg: str) -> DatasetError:
        """DatasetError '<file>, row r (line L of the file), column 'c': msg' (``row`` 0-based)."""
        parts = [self.where]
        if row is not None:
            parts.append(f"row {row + 1} (line {int(self.lines[row])} of the file)")
        if column is not None:
            parts.append(f"column '{column}'")
        return DatasetError(", ".join(parts) + ": " + msg, file=self.where,
                            row=None if row is None else row + 1, column=column)

    def line_offset(self) -> int | None:
        """File line minus data row when that is the same for every row (1 for a plain CSV with one
        header line), else None (blank, comment or metadata lines in between)."""
        if len(self.lines) == 0:
            return None
        off = int(self.lines[0]) - 1
        return off if np.array_equal(self.lines, np.arange(len(self.lines)) + 1 + off) else None


def read_lines(path: Path, encoding: str | None, where: str) -> list[str]:
    """The lines of a text file: ``encoding``, or UTF-8 (with or without BOM) falling back to
    cp1252 (Windows tracker software: '°', 'µ' in headers)."""
    if not path.is_file():
        raise DatasetError(f"{where}: file not found", file=where)
    raw = path.read_bytes()
    try:
        text = raw.decode(encoding or "utf-8-sig")
    except UnicodeDecodeError:
        if encoding:
            raise DatasetError(f"{where}: cannot be decoded as {encoding}", file=where) from None
        text = raw.decode("cp1252", errors="replace")
    return text.splitlines()


def delimiter_name(delimiter: str) -> str:
    """How a message names a delimiter: ``"';'"``, ``"tab"``, ``"whitespace"``..."""
    return _DELIMITER_NAMES.get(delimiter, repr(delimiter))


def detect_delimiter(header_line: str, decimal: str) -> str:
    """The delimiter a header line uses: tab, ';', '|', ',' (with a decimal comma: only a comma outside
    quoted fields, ``"A1","A2"`` / ``"-101,03","2,5"``, or between names without blanks, ``A1,A2``), else
    whitespace."""
    for d in ("\t", ";", "|"):
        if d in header_line:
            return d
    if "," in header_line and decimal != ",":
        return ","
    if "," in header_line:
        outside = re.sub(r'"[^"]*"', "", header_line.strip())
        if '"' in header_line and "," in outside:
            return ","  # quoted fields separated by commas (the decimal commas sit inside the quotes)
        if "," in outside and not re.search(r"\s", outside) and re.search(r"[A-Za-z_]", outside):
            return ","  # names separated by commas, no blanks: not a whitespace-separated line
    return " "


def split_lines(lines: list[str], delimiter: str) -> list[list[str]]:
    """Lines -> stripped cells (CSV quoting understood; ``" "`` = runs of whitespace)."""
    if delimiter == " ":
        return [ln.split() for ln in lines]
    return [[c.strip() for c in row] for row in csv.reader(lines, delimiter=delimiter)]


def read_delimited(
    path: str | Path,
    *,
    delimiter: str | None = None,
    decimal: str = ".",
    skip_rows: int = 0,
    header: bool = True,
    comment: str | None = None,
    drop_lines=(),
    encoding: str | None = None,
    allow_empty_names: bool = False,
    groups: bool = False,
    group_lines=None,
    layout_hint: str = "declare delimiter, skip_rows or comment if this is not the layout",
) -> TextTable:
    """Read a delimited text file: one header line (``header=False``: columns named 1, 2, ...), then
    one row per line.

    ``skip_rows`` lines above the header are skipped; blank lines and ``comment`` lines are skipped
    anywhere; ``drop_lines`` (1-based file lines) are dropped. ``delimiter`` None: detected from the
    header line (:func:`detect_delimiter`). A trailing delimiter on a line is tolerated; a row with
    another number of cells than the header is an error naming its row and line (``layout_hint``
    says what to check). Duplicate (and, unless ``allow_empty_names``, empty) column names are
    errors. A header without data rows gives a table with no rows.

    ``groups`` (the table importer's multi-row headers, OptiTrack Motive, Vicon): names that repeat
    or are empty get the labels of group lines above the header joined in front (``"Tool Rotation
    X"``, :func:`group_names`): the 1-based file lines ``group_lines``, or, when None, the fewest of
    the lines directly above the header (up to a blank line) that make the names unique. A name still
    empty becomes ``col<k>`` (k = 1-based column number).
    """
    where = str(path)
    text = read_lines(Path(path), encoding, where)
    numbered = [(i, ln) for i, ln in enumerate(text, start=1)][skip_rows:]
    numbered = [(i, ln) for i, ln in numbered if ln.strip() and not (comment and ln.lstrip().startswith(comment))]
    if not numbered:
        if not any(ln.strip() for ln in text):
            raise DatasetError(f"{where}: the file is empty (a header line is required)", file=where)
        raise DatasetError(f"{where}: no lines left after skipping {skip_rows} line(s), blank and comment lines",
                           file=where)
    delim = delimiter or detect_delimiter(numbered[0][1], decimal)
    drop = set(drop_lines)
    if not header:
        body = [(i, ln) for i, ln in numbered if i not in drop]
        width = len(split_lines([body[0][1]], delim)[0]) if body else 0
        names = [str(k + 1) for k in range(width)]
    else:
        names, body = split_lines([numbered[0][1]], delim)[0], [(i, ln) for i, ln in numbered[1:] if i not in drop]
    raw_width = len(names)
    cells = split_lines([ln for _, ln in body], delim)
    while names and names[-1] == "" and all(len(r) == len(names) and r[-1] == "" for r in cells):
        names, cells = names[:-1], [r[:-1] for r in cells]  # every line ends with the delimiter
    used_groups: list[int] = []
    if header and groups:
        names, used_groups = group_names(text, numbered[0][0], names, raw_width, delim, comment, group_lines, where)
    seen = set()
    for h in names:
        if h == "" and not allow_empty_names:
            raise DatasetError(f"{where}, line {numbered[0][0]}: the header has an empty column name", file=where)
        if h in seen:
            hint = ""
            if groups:
                hint = (f"; no line above the header (line {numbered[0][0]}) tells the columns apart: name the lines that "
                        "label the groups with group_rows = [..] (--group-rows), or read without a header (header_row = 0 "
                        "with skip_rows = the lines above the data; columns named 1, 2, ...)")
            elif all(re.fullmatch(r"\s*[-+]?(\d+[.,]?\d*|[.,]\d+)([eE][-+]?\d+)?\s*", c) for c in names):
                hint = ("; the first line holds numbers, not column names: the file has no header line (add one naming "
                        "the columns, or map them: hykin import table FILE --suggest)")
            raise DatasetError(f"{where}, column '{h}': appears twice in the header{hint}", file=where, column=h)
        seen.add(h)
    t = TextTable(where, names, cells, np.array([i for i, _ in body], dtype=np.int64), delim, used_groups)
    for r, row in enumerate(cells):
        if len(row) > len(names) and not any(row[len(names):]):
            cells[r] = row[:len(names)]  # trailing delimiter(s) on this line only
        elif len(row) != len(names):
            raise t.error(r, None, f"has {len(row)} cells, the header has {len(names)} "
                          f"(delimiter: {delimiter_name(delim)}; {layout_hint})")
    return t


def _align_group(cells: list[str], raw_width: int, width: int) -> list[str] | None:
    """A group line's cells under the header's ``width`` columns (``raw_width`` before trailing empty
    names were cut): extra leading empty cells dropped (the line is aligned on its right end), trailing
    empty cells cut, a short line padded; None when it cannot be aligned."""
    if len(cells) > raw_width and not any(cells[:len(cells) - raw_width]):
        cells = cells[len(cells) - raw_width:]
    if any(cells[width:]):
        return None
    cells = cells[:width] + [""] * (width - len(cells))
    if sum(1 for c in cells if c) * 2 < width:  # sparse (Vicon: the label over the first column of its group)
        last = ""
        cells = [last := c if c else last for c in cells]
    return cells


def _joined(names: list[str], rows: list[list[str]]) -> list[str]:
    """Names with the group labels of ``rows`` joined in front where a name repeats or is empty, and on
    every column of such a group (same labels); empty names left empty."""
    need = {j for j, h in enumerate(names) if h == "" or names.count(h) > 1}
    labels = [tuple(r[j] for r in rows) for j in range(len(names))]
    tagged = {labels[j] for j in need if any(labels[j])}
    out = []
    for j, h in enumerate(names):
        if j in need or labels[j] in tagged:
            out.append(" ".join([c for c in labels[j] if c] + ([h] if h else [])))
        else:
            out.append(h)
    return out


def _n_dup(names: list[str]) -> int:
    return sum(1 for h in names if h == "" or names.count(h) > 1)


def group_names(text: list[str], header_line: int, names: list[str], raw_width: int, delim: str, comment: str | None,
                group_lines, where: str) -> tuple[list[str], list[int]]:
    """Unique column names for a header whose names repeat (see :func:`read_delimited`, ``groups``):
    ``(names, the group lines used)``. Lines chosen automatically label groups (at most half as many
    labels as repeated names), each one taken only when it tells more columns apart."""
    if group_lines is None and not _n_dup(names):
        return names, []
    cand: dict[int, list[str]] = {}
    if group_lines is not None:
        for ln in group_lines:
            if not 1 <= ln < header_line or not text[ln - 1].strip():
                raise DatasetError(f"{where}, line {ln}: group_rows must name non-blank lines above the header "
                                   f"(line {header_line})", file=where)
            cells = _align_group(split_lines([text[ln - 1]], delim)[0], raw_width, len(names))
            if cells is None:
                raise DatasetError(f"{where}, line {ln}: has more cells than the header (line {header_line}) and cannot "
                                   "label its columns; is it a group line?", file=where)
            cand[ln] = cells
        chosen = sorted(cand)
    else:
        ln = header_line - 1
        while ln >= 1 and header_line - ln <= 8 and text[ln - 1].strip() and not (comment and text[ln - 1].lstrip().startswith(comment)):
            cells = _align_group(split_lines([text[ln - 1]], delim)[0], raw_width, len(names))
            if cells is None:
                break
            dup = [j for j, h in enumerate(names) if h == "" or names.count(h) > 1]
            labels = {cells[j] for j in dup if cells[j]}
            if labels and len(labels) * 2 <= max(len(dup), 2):
                cand[ln] = cells
            ln -= 1
        chosen = []
        while _n_dup(_joined(names, [cand[c] for c in sorted(chosen)])) and len(chosen) < len(cand):
            def score(c):
                rows = [cand[x] for x in sorted(chosen + [c])]
                labels = set(cand[c])
                return (_n_dup(_joined(names, rows)), -len(labels), -sum(bool(re.search("[A-Za-z]", x)) for x in labels))
            best = min((c for c in cand if c not in chosen), key=score)
            if score(best)[0] >= _n_dup(_joined(names, [cand[c] for c in sorted(chosen)])):
                break
            chosen.append(best)
        chosen.sort()
    out = _joined(names, [cand[c] for c in chosen])
    return [h or f"col{j + 1}" for j, h in enumerate(out)], chosen


_UNIT_CELL = re.compile(r"[\[(]?\s*(?:[a-zA-Zµ°%/]+[a-zA-Z0-9µ°%/^*.]*|°)\s*[\])]?")


def _units_row(cells: list[str]) -> bool:
    """Whether a row reads like a units line: no number in it, some cells units (``mm``, ``[deg]``, ``°``)."""
    full = [c.strip() for c in cells if c.strip()]
    if not full:
        return False
    for c in full:
        try:
            float(c.replace(",", "."))
            return False
        except ValueError:
            pass
    return all(_UNIT_CELL.fullmatch(c) for c in full)


def float_column(t: TextTable, name: str, decimal: str = ".", *, allow_missing: bool = False,
                 finite: bool = True, empty_hint: str | None = None) -> np.ndarray:
    """Column ``name`` as float64 ``(N,)``.

    Empty and non-numeric cells are errors naming the row, line and likely cause (decimal comma,
    thousands separator, units line under the header). ``finite``: NaN/inf cells are errors too.
    ``allow_missing``: empty and NaN cells become NaN (a tracker stream losing the beam).
    ``empty_hint``: what to do about an empty cell (default: leave such rows out with ``where``).
    """
    cells = t.col(name)
    conv = [c.replace(decimal, ".") for c in cells] if decimal != "." else cells
    if allow_missing:
        conv = [c if c.strip() else "nan" for c in conv]
    try:
        arr = np.asarray(conv, dtype=np.float64)
    except ValueError:
        arr = None
    if arr is None:
        for r, c in enumerate(conv):
            try:
                float(c)
            except ValueError:
                raw = cells[r]
                line = int(t.lines[r]) if len(t.lines) > r else r + 2
                if r == 0 and _units_row(t.rows[0]):
                    units = ", ".join(repr(c) for c in t.rows[0] if c.strip())
                    shown = repr(raw) if raw.strip() else "'(empty)'"
                    cause = (f"cell {shown} is not a number: row 1 looks like a units "
                             f"line under the header ({units}): drop it with drop_rows = [{line}] (--drop-rows "
                             f"{line}; --skip-rows skips lines above the header)")
                elif not raw.strip():
                    cause = ("cell '(empty)' is not a number: the cell is empty " + (empty_hint or (
                        f"(a marker or beam lost in that row? leave such rows out with where = [\"{name} != \"] "
                        f"in a mapping, `hykin import table FILE --where '{name} != '`)")))
                elif decimal == "," and re.fullmatch(r"[+-]?\d{1,3}(\.\d{3})+(,\d*)?", raw):
                    cause = (f"{raw!r} has a thousands separator '.' (European digit grouping, "
                             f"{raw.replace('.', '').replace(',', '.')} with a decimal point): export the file "
                             "without digit grouping (thousands separators)")
                elif decimal == "." and re.fullmatch(r"[+-]?\d{1,3}(,\d{3})+(\.\d*)?", raw):
                    cause = (f"{raw!r} has a thousands separator ',' (digit grouping, {raw.replace(',', '')}): export "
                             "the file without digit grouping (thousands separators)")
                elif decimal == "." and re.fullmatch(r"[+-]?\d*,\d+([eE][+-]?\d+)?", raw):
                    cause = f"{raw!r} looks like a decimal comma: declare decimal = \",\" (--decimal ,)"
                elif decimal == "," and re.fullmatch(r"[+-]?\d*\.\d+([eE][+-]?\d+)?", raw):
                    cause = f"{raw!r} has a decimal point but decimal = \",\" was declared"
                else:
                    cause = f"cell {raw!r} is not a number"
                    if r == 0 and re.search(r"[A-Za-z°µ\[\]]", raw):
                        cause += f" (a units line under the header? drop it with drop_rows = [{int(t.lines[0])}])"
                raise t.error(r, name, cause)
    if finite and not allow_missing:
        bad = ~np.isfinite(arr)
        if bad.any():
            r = int(np.argmax(bad))
            raise t.error(r, name, f"value {_shown(cells[r])} is not finite (NaN or inf); every mapped cell must be a number")
    return arr


def with_file_line(e: DatasetError, lines: np.ndarray) -> DatasetError:
    """``e`` (naming a data row ``e.row`` but no line) with "(line L of the file)" after the row,
    ``lines`` ``(N,)`` being the file line of each data row (:attr:`TextTable.lines`)."""
    line = int(lines[e.row - 1])
    msg = str(e).replace(f"row {e.row}", f"row {e.row} (line {line} of the file)", 1)
    return DatasetError(msg, file=e.file, row=e.row, column=e.column)


def lenient_column(cells: list[str], decimal: str = ".") -> np.ndarray:
    """Cells -> float64 when all parse, else the cells themselves as strings (extras kept as read)."""
    conv = [c.replace(decimal, ".") for c in cells] if decimal != "." else cells
    try:
        return np.asarray(conv, dtype=np.float64)
    except ValueError:
        return np.asarray(cells, dtype=str)


def _shown(v) -> str:
    """A cell as the file has it (a float as ``nan`` / ``inf``, not numpy's repr)."""
    return repr(v) if isinstance(v, str) else str(float(v))
