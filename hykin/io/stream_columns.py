"""Large numeric logs (a tracker streaming at kHz for hours): selected columns, read in chunks.

:mod:`hykin.io.text_table` reads any delimited layout cell by cell, which is what a tracker's export
with units rows, decimal commas and comments needs, but it holds every cell as text. A stream of
millions of samples in the plain layout (comma-separated CSV with one header line, or Parquet) is
read here instead: only the named columns, parsed by pyarrow in blocks of ``block_bytes`` (CSV) or
row groups (Parquet), so memory is the float64 result plus one block, not the file's text.

Empty cells and ``nan`` are NaN where a column allows missing values (a tracker losing the beam) and
an error naming the file, row and column elsewhere.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .dataset import DatasetError

__all__ = ["header_of", "read_columns"]


def header_of(path: str | Path) -> list[str]:
    """Column names of a CSV (first line) or Parquet file."""
    p = Path(path)
    if p.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        return list(pq.ParquetFile(p).schema_arrow.names)
    with open(p, encoding="utf-8-sig") as fh:
        line = fh.readline().rstrip("\r\n")
    return [c.strip() for c in line.split(",")]


def read_columns(path: str | Path, columns: list[str], *, allow_missing=(), block_bytes: int = 16 << 20,
                 progress=None) -> dict[str, np.ndarray]:
    """``{name: (N,) float64}`` for ``columns`` of a CSV/Parquet file (module docstring).

    allow_missing: names whose empty / NaN cells become NaN. progress: called with the rows read so far."""
    import pyarrow as pa

    where = str(path)
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"{where}: file not found", file=where)
    head = header_of(p)
    for c in columns:
        if c not in head:
            raise DatasetError(f"{where}: no column {c!r}; the header is: {', '.join(head)}", file=where, column=c)
    parts: dict[str, list] = {c: [] for c in columns}
    n = 0
    try:
        if p.suffix.lower() == ".parquet":
            import pyarrow.parquet as pq

            batches = pq.ParquetFile(p).iter_batches(columns=columns)
        else:
            import pyarrow.csv as pacsv

            batches = pacsv.open_csv(p, read_options=pacsv.ReadOptions(block_size=block_bytes),
                                     convert_options=pacsv.ConvertOptions(include_columns=columns,
                                                                          column_types={c: pa.float64() for c in columns}))
        for b in batches:
            for c in columns:
                parts[c].append(b.column(c).cast(pa.float64()).to_numpy(zero_copy_only=False))
            n += b.num_rows
            if progress is not None:
                progress(n)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as e:
        msg = str(e).splitlines()[0]
        raise DatasetError(f"{where}: {msg} (a value that is not a number: this reader takes plain comma-separated "
                           "numbers; use a mapping file for other layouts)", file=where) from None
    out = {c: np.concatenate(v) if v else np.zeros(0) for c, v in parts.items()}
    allow = set(allow_missing)
    for c, v in out.items():
        if c in allow:
            continue
        bad = ~np.isfinite(v)
        if bad.any():
            r = int(np.argmax(bad))
            raise DatasetError(f"{where}: row {r + 1} (line {r + 2}), column {c}: empty or not finite", file=where,
                               row=r + 1, column=c)
    return out
