"""Read a contract file, validate it, and report errors at the user's line."""

from __future__ import annotations

import difflib

import fsspec
import pydantic
import yaml

from bagport.contract.model import Contract
from bagport.contract.plan import ContractPlan, compile_contract
from bagport.decode.custom import resolve_decoder
from bagport.errors import ContractError
from bagport.yamlsource import YamlSource, load_yaml, primary_error

__all__ = ["load_contract", "parse_contract"]


def _read_text(uri: str) -> str:
    try:
        with fsspec.open(uri, "r", encoding="utf-8") as handle:
            return str(handle.read())
    except FileNotFoundError as err:
        raise ContractError("file does not exist", file=uri, fix="check the --contract path.") from err
    except (OSError, UnicodeDecodeError) as err:
        raise ContractError(f"cannot be read ({err})", file=uri, fix="check the --contract path.") from err


def _suggest(loc: tuple[int | str, ...], err_type: str) -> str:
    if err_type != "extra_forbidden" or not loc:
        return ""
    name = str(loc[-1])
    known = _known_fields(loc[:-1])
    close = difflib.get_close_matches(name, known, n=1)
    if close:
        return f"did you mean '{close[0]}'?"
    return f"remove it; allowed here: {', '.join(sorted(known))}."


def _known_fields(parent: tuple[int | str, ...]) -> list[str]:
    model: type[pydantic.BaseModel] = Contract
    for part in parent:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(str(part))
        if field is None:
            return []
        inner = _model_in(field.annotation)
        if inner is None:
            return []
        model = inner
    return list(model.model_fields)


def _model_in(annotation: object) -> type[pydantic.BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _from_validation(err: pydantic.ValidationError, source: YamlSource) -> ContractError:
    errors = err.errors()
    first = primary_error(err)
    loc = tuple(first["loc"])
    field = ".".join(str(p) if isinstance(p, str) else f"[{p}]" for p in loc).replace(".[", "[")
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "missing":
        msg = "required field is missing"
    elif first["type"] == "extra_forbidden":
        msg = "unknown field"
    more = f" ({len(errors) - 1} more problem(s) after this one)" if len(errors) > 1 else ""
    fix = _suggest(loc, first["type"]) or "see the contract format in the README."
    return ContractError(msg + more, file=source.name, line=source.line_of(loc), field=field, fix=fix)


def parse_contract(text: str, name: str = "contract") -> ContractPlan:
    """Parse and validate contract YAML ``text``; ``name`` is used in error messages."""
    try:
        source = load_yaml(text, name)
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
            fix="see the contract format in the README.",
        )
    try:
        contract = Contract.model_validate(source.data)
    except pydantic.ValidationError as err:
        raise _from_validation(err, source) from err
    plan = compile_contract(contract, name)
    for feature in plan.features:
        for src in feature.sources:
            if src.decoder is not None:
                resolve_decoder(src.decoder, where=f"{name} ({src.key} on {src.topic})")
    return plan


def load_contract(uri: str) -> ContractPlan:
    """Load a contract from a local path or any fsspec URI."""
    return parse_contract(_read_text(uri), uri)
