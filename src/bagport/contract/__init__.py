"""Contracts: Rosetta-compatible YAML mapping ROS topics to LeRobot features."""

from __future__ import annotations

from bagport.contract.load import load_contract, parse_contract
from bagport.contract.model import Contract, normalize_msgtype
from bagport.contract.plan import ContractPlan, FeatureKind, FeatureSpec, SourceSpec, compile_contract

__all__ = [
    "Contract",
    "ContractPlan",
    "FeatureKind",
    "FeatureSpec",
    "SourceSpec",
    "compile_contract",
    "load_contract",
    "normalize_msgtype",
    "parse_contract",
]
