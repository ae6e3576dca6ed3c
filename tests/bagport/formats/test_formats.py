"""Checks made before any work: each format's package is installed, each output free."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from bagport.config import ConvertConfig
from bagport.errors import BagportError, DatasetWriteError
from bagport.formats import check_format_outputs


def _config(out: Path, *formats: str, overwrite: bool = False) -> ConvertConfig:
    values = {"manifest": "m.yaml", "contract": "c.yaml", "output": str(out), "formats": formats}
    return ConvertConfig.model_validate({**values, "overwrite": overwrite})


@pytest.mark.parametrize(("fmt", "package"), [("hdf5", "h5py"), ("robodm", "robodm")])
def test_a_missing_package_is_named_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fmt: str, package: str
) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None if name == package else real(name))
    with pytest.raises(BagportError, match=rf"--format {fmt} needs .* Fix: pip install 'bagport\[{fmt}\]'"):
        check_format_outputs(_config(tmp_path / "ds", "lerobot", fmt))


def test_an_existing_output_of_another_format_is_refused_unless_overwrite(tmp_path: Path) -> None:
    (tmp_path / "ds.hdf5").mkdir()
    with pytest.raises(DatasetWriteError, match=r"ds\.hdf5 already exists; nothing was written"):
        check_format_outputs(_config(tmp_path / "ds", "lerobot", "hdf5"))
    check_format_outputs(_config(tmp_path / "ds", "lerobot", "hdf5", overwrite=True))
    check_format_outputs(_config(tmp_path / "ds.hdf5", "hdf5"))  # the primary output: plan_run's own check
