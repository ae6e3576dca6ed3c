"""ConvertConfig's output formats: where each goes, and what is refused."""

from __future__ import annotations

import pydantic
import pytest

from bagport.config import ConvertConfig


def _config(**values: object) -> ConvertConfig:
    return ConvertConfig.model_validate(
        {"manifest": "m.yaml", "contract": "c.yaml", "output": "s3://b/ds/", **values}
    )


def test_lerobot_is_the_default_and_goes_to_output() -> None:
    assert _config().format_outputs() == {"lerobot": "s3://b/ds/"}


def test_other_formats_go_beside_the_lerobot_output() -> None:
    outputs = _config(formats=["lerobot", "robodm", "hdf5"]).format_outputs()
    assert outputs == {"lerobot": "s3://b/ds/", "robodm": "s3://b/ds.robodm", "hdf5": "s3://b/ds.hdf5"}


def test_without_lerobot_the_first_format_goes_to_output() -> None:
    assert _config(formats=["hdf5", "robodm"]).format_outputs() == {
        "hdf5": "s3://b/ds/",
        "robodm": "s3://b/ds.robodm",
    }


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"formats": []}, "give each of lerobot, hdf5, robodm at most once"),
        ({"formats": ["hdf5", "hdf5"]}, "give each of lerobot, hdf5, robodm at most once"),
        ({"formats": ["parquet"]}, "Input should be 'lerobot', 'hdf5' or 'robodm'"),
        ({"formats": ["lerobot", "hdf5"], "append": True}, "append adds to a LeRobot dataset only"),
        ({"hdf5_jpeg_quality": 0, "formats": ["hdf5"]}, "greater than or equal to 1"),
        ({"hdf5_jpeg_quality": 50}, "applies to --format hdf5 only"),
    ],
    ids=["none", "twice", "unknown", "append", "jpeg-quality", "jpeg-without-hdf5"],
)
def test_refused_formats(values: dict[str, object], message: str) -> None:
    with pytest.raises(pydantic.ValidationError, match=message):
        _config(**values)


def test_overwrite_and_append_together_are_refused() -> None:
    """One replaces the dataset, the other adds to it: both given (a run file's overwrite: true and --append
    on the command line) is an error, not a silent append."""
    with pytest.raises(pydantic.ValidationError, match="overwrite and append both given"):
        _config(overwrite=True, append=True)
    assert _config(append=True).append and _config(overwrite=True).overwrite
