"""The README's command list is the CLI's reference: every command, subcommand and option of the
installed CLI must appear in it (so a new option cannot land undocumented)."""

from __future__ import annotations

import re
from pathlib import Path

import typer

from hykin.cli import app

README = Path(__file__).resolve().parents[1] / "README.md"


def _cli_commands() -> dict[str, set[tuple[str, ...]]]:
    """``{"fit": {"--val", ...}, "import table": {...}, ...}`` from the Typer app itself."""
    root = typer.main.get_command(app)
    ctx = typer.Context(root)
    out: dict[str, set[tuple[str, ...]]] = {}
    for name in root.list_commands(ctx):
        cmd = root.get_command(ctx, name)
        subs = [(name, cmd)]
        if hasattr(cmd, "list_commands"):  # a group (typer 0.29 vendors click: not a click.Group)
            subs = [(f"{name} {s}", cmd.get_command(ctx, s)) for s in cmd.list_commands(ctx)]
        for full, c in subs:
            opts = set()
            for p in c.params:
                if p.param_type_name != "option" or p.name == "help":
                    continue
                opts.add(tuple(p.opts))  # any spelling of the option counts (-o or --out)
                opts.update((o,) for o in p.secondary_opts)
            out[full] = opts
    return out


def _readme_block() -> str:
    text = README.read_text()
    m = re.search(r"## Command line\n.*?```[a-z]*\n(.*?)```", text, flags=re.DOTALL)
    assert m, "README has no '## Command line' code block"
    return m.group(1)


def test_every_command_and_option_is_in_the_readme_command_list():
    # an entry is a line "hykin CMD ..." plus the indented lines that continue it
    entries: list[str] = []
    for ln in _readme_block().splitlines():
        if ln.startswith("hykin "):
            entries.append(ln)
        elif ln.startswith(" ") and entries:
            entries[-1] += " " + ln.strip()
    missing = []
    for cmd, opts in _cli_commands().items():
        mine = [e for e in entries if re.match(rf"hykin {re.escape(cmd)}(\s|$)", e)]
        if not mine:
            missing.append(f"command 'hykin {cmd}'")
            continue
        # the list's legend: a lone "U" stands for [--length-unit ..] [--angle-unit ..]
        text = re.sub(r"(?<=\s)U(?=\s|$)", "--length-unit --angle-unit", " ".join(mine))
        for spellings in sorted(opts):
            if not any(re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", text) for o in spellings):
                missing.append(f"'hykin {cmd}' option {spellings[-1]}")
    assert not missing, "README command list lacks: " + "; ".join(missing)


def test_version_flag(capsys):
    import pytest

    from hykin import __version__
    from hykin.cli import main

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code in (0, None)
    assert capsys.readouterr().out.strip() == f"hykin {__version__}"
