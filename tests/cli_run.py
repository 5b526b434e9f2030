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


def run_captured(argv) -> tuple[object, str, str]:
    """Run ``hykin ARGV`` in-process without pytest's capsys (Hypothesis tests, the battery benchmark):
    (exit code, or "crash" when an exception escaped the CLI, stdout, stderr with the traceback)."""
    import contextlib
    import io
    import traceback

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main([str(a) for a in argv])
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except Exception:  # a crash is a verdict of its own, never stops a battery
            traceback.print_exc(file=err)
            code = "crash"
    return code, out.getvalue(), err.getvalue()
