"""Write a generated section of BENCHMARKS.md between its markers; the prose around it stays."""

from __future__ import annotations

from pathlib import Path

__all__ = ["write_section"]


def write_section(report: Path, name: str, body: str) -> None:
    """Replace what stands between ``<!-- name:start -->`` and ``<!-- name:end -->`` with ``body``
    (the markers are appended when the file, or the section, does not exist yet)."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    section = f"{start}\n{body}\n{end}"
    text = report.read_text() if report.exists() else "# Benchmarks\n"
    if start in text and end in text:
        text = text[: text.index(start)] + section + text[text.index(end) + len(end) :]
    else:
        text += "\n" + section + "\n"
    report.write_text(text)
