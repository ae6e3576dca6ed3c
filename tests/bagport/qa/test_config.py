"""QA thresholds: configs/qa.yaml documents the defaults exactly; mistakes point at the line."""

from __future__ import annotations

import pytest

from bagport.errors import ContractError
from bagport.qa import QAConfig, load_qa_config
from tests.helpers import REPO


def test_configs_qa_yaml_spells_out_the_defaults() -> None:
    assert load_qa_config((REPO / "configs" / "qa.yaml").read_text()) == QAConfig()


def test_unknown_key_names_the_line_and_the_nearest_key() -> None:
    text = "on_fail: exclude\nvalues:\n  non_finit: {fail: 1}\n"
    with pytest.raises(
        ContractError, match=r"qa.yaml:3 \(values.non_finit\): unknown field.*did you mean 'non_finite'"
    ):
        load_qa_config(text, "qa.yaml")


def test_bad_policy_is_refused() -> None:
    with pytest.raises(ContractError, match=r"qa.yaml:1 \(on_fail\).*'exclude', 'keep' or 'fail_run'"):
        load_qa_config("on_fail: skip\n", "qa.yaml")
