"""Read a contract file, validate it, and report errors at the user's line."""

from __future__ import annotations

import pydantic
import yaml

from bagport.contract.model import MAX_FPS, MAX_RESIZE_PX, Contract
from bagport.contract.plan import ContractPlan, compile_contract
from bagport.decode.custom import resolve_decoder
from bagport.errors import ContractError
from bagport.uris import read_text_file
from bagport.yamlsource import DuplicateKeyError, explain_validation, field_of, load_yaml

__all__ = ["load_contract", "parse_contract"]

_FIELD_FIXES = {
    "fps": f"fps is the dataset's frame rate, a whole number of frames per second from 1 to {MAX_FPS}, "
    "such as 30.",
    "resize": f"image.resize is the [height, width] frames are scaled to, each side 1 to {MAX_RESIZE_PX} "
    "pixels, e.g. [240, 320].",
    "key": "use '.' to structure keys (observation.images.front); LeRobot forbids '/'.",
    "type": "write the ROS type as 'pkg/msg/Type', e.g. sensor_msgs/msg/JointState.",
    "topic": "ROS topic names are absolute: '/joint_states'.",
}


def parse_contract(text: str, name: str = "contract") -> ContractPlan:
    """Parse and validate contract YAML ``text``; ``name`` is used in error messages."""
    try:
        source = load_yaml(text, name)
    except DuplicateKeyError as err:
        raise ContractError(
            err.said,
            file=name,
            line=err.line,
            field=field_of(err.loc) or None,
            fix=f"keep one '{err.key}:'.",
        ) from err
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(err, "problem", None) or str(err)
        raise ContractError(f"is not valid YAML: {problem}", file=name, line=line) from err
    if not isinstance(source.data, dict):
        raise ContractError(
            "must be a YAML mapping with robot_type, fps, observations, actions",
            file=name,
            line=1,
            fix="see the contract format in docs/contracts.md.",
        )
    try:
        contract = Contract.model_validate(source.data)
    except pydantic.ValidationError as err:
        default_fix = "see the contract format in docs/contracts.md."
        problem = explain_validation(err, source, Contract, default_fix)
        last = problem.field.rsplit(".", 1)[-1].split("[", 1)[0]
        fix = problem.fix
        if problem.fix == default_fix:  # a field's own advice on its format: for a value, not a missing key
            fix = f"add its '{last}:' key; {default_fix}" if problem.missing else _FIELD_FIXES.get(last, fix)
        raise ContractError(problem.what, file=name, line=problem.line, field=problem.field, fix=fix) from err
    plan = compile_contract(contract, name, source.line_of)
    for src in plan.sources:
        if src.decoder is not None:
            field = f"{src.section}[key={src.key}].decoder"
            resolve_decoder(src.decoder, file=name, line=src.line, field=field)
    return plan


def load_contract(uri: str) -> ContractPlan:
    """Load a contract from a local path or any fsspec URI."""
    text = read_text_file(uri, error=ContractError, subject="file", fix="check the --contract path.")
    return parse_contract(text, uri)
