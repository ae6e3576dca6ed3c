"""QA thresholds: configs/qa.yaml documents the defaults exactly; mistakes point at the line."""

from __future__ import annotations

import pytest
import yaml

from bagport.errors import ContractError
from bagport.qa import QAConfig, load_qa_config
from tests.helpers import REPO


def test_configs_qa_yaml_spells_out_the_defaults() -> None:
    text = (REPO / "configs" / "qa.yaml").read_text()
    assert load_qa_config(text) == QAConfig()
    # every option is written out, not only equal by falling back to a default
    written = yaml.safe_load(text)
    for group, options in QAConfig().model_dump().items():
        if isinstance(options, dict):
            assert sorted(written[group]) == sorted(options), group
        else:
            assert group in written


def test_unknown_key_names_the_line_and_the_nearest_key() -> None:
    text = "on_fail: exclude\nvalues:\n  non_finit: {fail: 1}\n"
    with pytest.raises(
        ContractError, match=r"qa.yaml:3 \(values.non_finit\): unknown field.*did you mean 'non_finite'"
    ):
        load_qa_config(text, "qa.yaml")


def test_bad_policy_is_refused() -> None:
    with pytest.raises(ContractError, match=r"qa.yaml:1 \(on_fail\).*'exclude', 'keep' or 'fail_run'"):
        load_qa_config("on_fail: skip\n", "qa.yaml")
