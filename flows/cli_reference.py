"""The CLI reference page of the docs, generated from the ``bagport`` argument parser itself.

Nobody writes an option by hand twice: ``make docs`` writes ``docs/cli.md`` with this, and a test fails
when the committed page differs from what the parser says.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

from flows.cli_config import COMMAND_LINE_ONLY, config_options

__all__ = ["render_cli_reference"]

_INTRO = """# CLI reference

Generated from the `bagport` argument parser (`make docs` runs `flows/cli_reference.py`): every
command, every option, its default. Errors print as one paragraph (what, where, how to fix);
`BAGPORT_DEBUG=1` shows the traceback. Exit codes: **0** everything converted (or passed QA);
**1** some episodes were excluded or failed as the QA policy says, or `--fail-fast` stopped the run;
**2** usage or input error, nothing written. A run outlives its console: when the reader of its output
goes away (`bagport convert ... | head`, a `tee` or log shipper that dies), it drops what it would have
printed and goes on to its dataset and its own exit code (the logs are still on the Prefect server). A run
ended by SIGTERM (a scheduler's time limit) stops at once, as a kill does, after one line saying that the
same command resumes it (exit status 143). `bagport --version` prints the installed version.
"""


def _subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str, argparse.ArgumentParser]]:
    """``(name, help, parser)`` of each subcommand of ``parser``, in the order they were added."""
    # argparse has no public walk of its subparsers: read its (stable) private lists.
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, helps.get(name, ""), sub


def _cell(text: str) -> str:
    text = text.replace("%%", "%")  # argparse's escape
    return " ".join(text.split()).replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _option_name(action: argparse.Action) -> str:
    if not action.option_strings:
        return f"`{action.metavar or action.dest}`"
    names = ", ".join(f"`{s}`" for s in action.option_strings)
    if action.nargs == 0:
        return names
    if action.choices:
        return f"{names} `{'\\|'.join(str(c) for c in action.choices)}`"
    return f"{names} `{action.metavar or action.dest.upper()}`"


def _default(action: argparse.Action) -> str:
    if action.required:
        return "required"
    if action.nargs == 0 or action.default in (None, argparse.SUPPRESS):
        return ""
    return f"`{action.default}`"


def _options_table(parser: argparse.ArgumentParser) -> list[str]:
    rows = [
        a for a in parser._actions if not isinstance(a, argparse._HelpAction | argparse._SubParsersAction)
    ]
    if not rows:
        return []
    lines = ["| argument | default | what it does |", "|---|---|---|"]
    lines += [f"| {_option_name(a)} | {_default(a)} | {_cell(a.help or '')} |" for a in rows]
    return [*lines, ""]


def _render(parser: argparse.ArgumentParser, path: str, help_text: str, level: int) -> list[str]:
    lines = [f"{'#' * level} `{path}`", ""]
    summary = _cell(parser.description or help_text)
    if summary:
        lines += [summary[:1].upper() + summary[1:].rstrip(".") + ".", ""]
    lines += ["```text", parser.format_usage().strip(), "```", ""]
    lines += _options_table(parser)
    for name, sub_help, sub in _subcommands(parser):
        lines += _render(sub, f"{path} {name}", sub_help, min(level + 1, 4))
    return lines


_KEYS_INTRO = """## Run options as keys

`convert`'s options are the fields of `ConvertConfig` (`src/bagport/config.py`), so a
`--config run.yaml` file and a deployment's `config` parameter take them as keys (see
[Run options](options.md)); the key of each option:
"""


def _config_keys() -> list[str]:
    """The run.yaml / deployment key of every ``convert`` option generated from ConvertConfig."""
    lines = [_KEYS_INTRO, "| key | option |", "|---|---|"]
    for name, _, option in config_options():
        if option.named:  # a preset's name, or the field's value itself
            lines.append(f"| `{option.named}` (a preset), or `{name}` (its settings) | `{option.flag}` |")
        else:
            lines.append(f"| `{name}` | `{option.flag}` |")
    flags = ", ".join(f"`{flag}`" for flag in COMMAND_LINE_ONLY.values())
    no_key = (
        f"Options about the command itself, not the run, have no key: {flags}. A `--config` file that "
        "gives one (`push_to_hub: true`) is refused with the flag to give instead."
    )
    return [*lines, "", no_key, ""]


def render_cli_reference(parser: argparse.ArgumentParser) -> str:
    """The Markdown reference of ``parser`` and all its subcommands, then the run options' keys."""
    lines = [_INTRO]
    for name, help_text, sub in _subcommands(parser):
        lines += _render(sub, f"{parser.prog} {name}", help_text, 2)
    lines += _config_keys()
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":  # `python -m flows.cli_reference docs/cli.md` (make docs)
    import sys
    from pathlib import Path

    from flows.cli import build_parser

    Path(sys.argv[1]).write_text(render_cli_reference(build_parser()), encoding="utf-8")
