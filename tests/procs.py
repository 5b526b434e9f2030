"""Processes from /proc (Linux), for the tests and benchmarks that find, time or stop Ray's processes
(not a test module)."""

from __future__ import annotations

import os

__all__ = ["alive", "descendants", "proc_table"]


def proc_table() -> dict:
    """pid -> ``(parent pid, command line, CPU seconds user + system)`` of every readable process."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                st = open(f"/proc/{d}/stat", encoding="utf-8").read()
                cmd = open(f"/proc/{d}/cmdline", "rb").read().replace(b"\0", b" ").decode("utf-8", "replace")
            except OSError:
                continue
            f = st[st.rindex(")") + 2:].split()
            out[int(d)] = (int(f[1]), cmd, (int(f[11]) + int(f[12])) / tick)
    return out


def descendants(pids, table: dict | None = None) -> list[int]:
    """Process ids below any of ``pids`` (an int or a list), from ``table`` (default: read now)."""
    table = proc_table() if table is None else table
    todo = [pids] if isinstance(pids, int) else list(pids)
    out: list[int] = []
    while todo:
        p = todo.pop()
        kids = [c for c, row in table.items() if row[0] == p and c not in out]
        out += kids
        todo += kids
    return out


def alive(pid: int) -> bool:
    """``pid`` exists and is not a zombie."""
    try:
        st = open(f"/proc/{pid}/stat", encoding="utf-8").read()
    except OSError:
        return False
    return st[st.rindex(")") + 2] != "Z"
