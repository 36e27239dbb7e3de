"""The command-line reference (``docs/cli.md``), generated from the typer app.

Run ``python -m eha.docgen > docs/cli.md`` after changing a command, an option or a help
text; ``tests/test_docs.py`` regenerates the page and fails when the checked-in copy is stale,
so the reference cannot drift from ``eha --help``.

The page is plain Markdown built from the click objects typer makes (not from the rich help
screens), so it does not depend on the terminal width. They are inspected by duck typing:
typer may bring its own copy of click. Defaults that the CLI reads from the library when
an option is parsed (:mod:`eha.cli.defaults`) are shown with their value.
"""

from __future__ import annotations

import inspect
import sys
from typing import Any, Iterator

HEADER = """# Command-line reference

Generated from the `eha` application by `python -m eha.docgen > docs/cli.md`; do not edit
by hand (`tests/test_docs.py` fails when this page and the application differ). Every command
also answers `--help`. Exit codes, and what happens with bad input: `docs/reliability.md`.
"""


def _context(cmd: Any, path: str) -> Any:
    """A context of ``cmd`` named ``path``, as click builds one to print its help."""
    return cmd.context_class(cmd, info_name=path)


def _subcommands(cmd: Any, path: str) -> list[tuple[str, Any]]:
    """A group's visible commands, in the order ``--help`` lists them (none for a command)."""
    if not hasattr(cmd, "list_commands"):
        return []
    ctx = _context(cmd, path)
    subs = [(name, cmd.get_command(ctx, name)) for name in cmd.list_commands(ctx)]
    return [(name, sub) for name, sub in subs if not sub.hidden]


def _commands(cmd: Any, path: str) -> Iterator[tuple[str, Any]]:
    """Every visible command under ``cmd`` (itself first), depth first."""
    yield path, cmd
    for name, sub in _subcommands(cmd, path):
        yield from _commands(sub, f"{path} {name}")


def _help_record(param: Any, ctx: Any) -> tuple[str, str]:
    """The option's line of ``--help`` (names with the type, help with default and range),
    with a default read from the library shown by its value instead of ``(dynamic)``."""
    names, text = param.get_help_record(ctx) or ("", "")
    if callable(param.default) and "(dynamic)" in text:
        value = param.default()
        shown = ",".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)
        text = text.replace("(dynamic)", shown)
    return names, text


def _cell(text: str) -> str:
    """One table cell: a single line, pipes escaped, ``<`` escaped so that a placeholder such
    as ``<file stem>`` is not taken for an HTML tag."""
    return " ".join(text.split()).replace("|", "\\|").replace("<", "\\<")


def _usage(cmd: Any, path: str) -> str:
    """The usage line of ``--help``, without the "Usage:" prefix."""
    return f"{path} " + " ".join(cmd.collect_usage_pieces(_context(cmd, path)))


def _section(path: str, cmd: Any) -> list[str]:
    """The lines of one command: heading, help text, subcommands, usage, arguments, options."""
    level = "#" * min(2 + path.count(" "), 4)
    lines = [f"{level} `{path}`", ""]
    help_text = inspect.cleandoc(cmd.help or "")
    if help_text:
        lines += [help_text, ""]
    subs = _subcommands(cmd, path)
    if subs:
        lines += ["| command | summary |", "|---|---|"]
        lines += [f"| `{path} {n}` | {_cell(c.get_short_help_str(limit=200))} |"
                  for n, c in subs]
        lines.append("")
    lines += ["```text", _usage(cmd, path), "```", ""]
    ctx = _context(cmd, path)
    for kind in ("argument", "option"):
        params = [p for p in cmd.params if p.param_type_name == kind and not p.hidden]
        if params:
            lines += [f"| {kind} | help |", "|---|---|"]
            lines += [f"| `{names}` | {_cell(text)} |"
                      for names, text in (_help_record(p, ctx) for p in params)]
            lines.append("")
    return lines


def render() -> str:
    """The whole reference page as Markdown text."""
    import typer

    from eha.cli import app

    root = typer.main.get_command(app)
    lines = [HEADER]
    for path, cmd in _commands(root, "eha"):
        lines += _section(path, cmd)
    return "\n".join(lines).rstrip("\n") + "\n"


def main() -> None:
    """Write the page to standard output."""
    sys.stdout.write(render())


if __name__ == "__main__":
    main()
