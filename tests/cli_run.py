"""Drive the CLI in-process from tests (shared by the CLI test modules; not a test module)."""

from __future__ import annotations

from hykin.cli import main


def run(argv, capsys):
    """Run ``hykin ARGV`` in-process; returns (exit code, stdout, stderr)."""
    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    out = capsys.readouterr()
    return code, out.out, out.err
