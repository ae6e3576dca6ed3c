"""Every error class has its section, with the fix, on the troubleshooting page."""

from __future__ import annotations

import re
from pathlib import Path

import bagport.errors

PAGE = Path(__file__).resolve().parents[2] / "docs" / "troubleshooting.md"


def test_every_error_class_has_a_section() -> None:
    headings = set(re.findall(r"(?m)^## (\w+)$", PAGE.read_text(encoding="utf-8")))
    public = {name for name in bagport.errors.__all__ if name != "BagportError"}
    assert public <= headings, f"document these on docs/troubleshooting.md: {sorted(public - headings)}"
