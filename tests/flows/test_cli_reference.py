"""The docs' CLI reference is generated from the parser: the committed page must match it."""

from __future__ import annotations

from pathlib import Path

from flows.cli import build_parser
from flows.cli_reference import render_cli_reference

PAGE = Path(__file__).resolve().parents[2] / "docs" / "cli.md"


def test_committed_page_matches_the_parser() -> None:
    expected = render_cli_reference(build_parser())
    assert PAGE.read_text(encoding="utf-8") == expected, (
        "docs/cli.md is stale: run `make docs` (it regenerates the page from flows/cli.py)"
    )


def test_every_command_and_option_is_listed() -> None:
    page = render_cli_reference(build_parser())
    for command in ("convert", "qa", "inspect", "validate", "contract check", "contract init", "synth"):
        assert f"## `bagport {command}`" in page
    for option in ("`--manifest`", "`--on-qa-fail` `exclude\\|keep\\|fail_run`", "`--every`", "`--bag`"):
        assert option in page
    assert "| `--contract` `CONTRACT` |  | contract YAML (Rosetta-compatible); required" in page
    assert "| `--runner` `process\\|thread\\|dask\\|ray` | `process` |" in page
