"""MkDocs hook: ``benchmarks.md`` is ``BENCHMARKS.md`` at the repository root (``make bench`` writes it),
so the site shows the figures without a second copy. Its links to ``docs/<page>.md`` (right from the
repository root) point at ``<page>.md`` in the site, which is built from ``docs/``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]


def on_files(files: Files, config: Any) -> Files:
    benchmarks = (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8").replace("](docs/", "](")
    files.append(File.generated(config, "benchmarks.md", content=benchmarks))
    return files
