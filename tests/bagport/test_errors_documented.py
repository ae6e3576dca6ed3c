"""Every error bagport raises on purpose has its place, with the fix, on the troubleshooting page."""

from __future__ import annotations

import re
from pathlib import Path

import bagport.errors
import bagport.formats.hdf5
import bagport.formats.robodm
import flows.convert
import flows.deployments

PAGE = Path(__file__).resolve().parents[2] / "docs" / "troubleshooting.md"


def _subclasses(cls: type[BaseException]) -> set[type[BaseException]]:
    found = set(cls.__subclasses__())
    for sub in list(found):
        found |= _subclasses(sub)
    return found


def test_every_error_class_of_the_library_has_a_section() -> None:
    headings = set(re.findall(r"(?m)^## (\w+)$", PAGE.read_text(encoding="utf-8")))
    public = {name for name in bagport.errors.__all__ if name != "BagportError"}
    assert public <= headings, f"document these on docs/troubleshooting.md: {sorted(public - headings)}"


def test_every_bagport_error_anywhere_is_named_on_the_page() -> None:
    """The flow's and the optional formats' errors too (imported above, so their classes exist)."""
    assert flows.convert and flows.deployments and bagport.formats.hdf5 and bagport.formats.robodm
    page = PAGE.read_text(encoding="utf-8")
    names = {cls.__name__ for cls in _subclasses(bagport.errors.BagportError)}
    missing = sorted(name for name in names if not name.startswith("_") and name not in page)
    assert not missing, f"document these on docs/troubleshooting.md: {missing}"
