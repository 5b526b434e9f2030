"""The ``hykin`` command line (DESIGN.md §4).

Every command turns bad input into a one-line error on stderr and a non-zero exit status; no
tracebacks. Heavy imports (torch) happen inside the commands that need them. Commands are defined in
the modules of this package, one family per module, and register on the shared Typer :data:`app`.
"""

from __future__ import annotations

import sys

from . import compensate, data, imports, model, plan, query, realtime, report, scale  # noqa: F401  (register the commands)
from .common import CLIError, app, interrupt_said

__all__ = ["CLIError", "app", "main"]


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: one-line errors, non-zero exit status."""
    import warnings

    # Warnings (e.g. queries outside the training region) as one readable line, no source echo.
    warnings.formatwarning = lambda message, category, *a, **k: f"hykin: warning: {message}\n"
    try:
        app(args=argv, prog_name="hykin")
    except SystemExit as e:
        if e.code == 130 and not interrupt_said():  # Ctrl-C: Typer turns KeyboardInterrupt into a silent 130
            print("hykin: interrupted", file=sys.stderr)
        raise
    except KeyboardInterrupt:
        print("hykin: interrupted", file=sys.stderr)
        sys.exit(130)
    except (CLIError, ValueError, OSError, KeyError, ImportError, RuntimeError) as e:
        msg = str(e).strip().splitlines()
        print(f"hykin: error: {msg[0] if msg else type(e).__name__}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
