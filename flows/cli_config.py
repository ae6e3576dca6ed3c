"""``bagport convert``'s run options, generated from :class:`~bagport.config.ConvertConfig`'s fields: the
command-line options (:func:`add_config_options`), ``--config run.yaml`` and the deployments' ``config``
parameter (:func:`resolve_options`) take the same keys, so a new field is written once, in the library."""

from __future__ import annotations

import argparse
import types
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import annotated_types
import yaml
from pydantic.fields import FieldInfo

from bagport.config import CliOption, ConvertConfig, cli_option
from bagport.errors import BagportError
from bagport.yamlsource import YamlSource, load_yaml

__all__ = [
    "COMMAND_LINE_ONLY",
    "POSITIVE_INT",
    "PRESETS",
    "add_config_options",
    "config_options",
    "convert_config",
    "load_encoder",
    "number_type",
    "resolve_options",
]


def load_encoder(value: str | None) -> dict[str, Any]:
    if not value:
        from bagport.video.settings import default_encoder  # noqa: PLC0415 - keep `--help` fast

        return default_encoder()
    path = Path(value)
    if not path.is_file():
        codecs = Path(__file__).resolve().parent.parent / "configs" / "codecs"
        preset = codecs / f"{value}.yaml"
        if "/" in value or not preset.is_file():
            presets = ", ".join(sorted(p.stem for p in codecs.glob("*.yaml")))
            raise BagportError(
                f"--codec {value}: no such file, and no preset of that name. Fix: give a preset ({presets}) "
                "or the path of a YAML file of encoder settings."
            )
        path = preset
    data = _yaml_file(path, f"--codec {value}") or {}
    if not isinstance(data, dict):
        raise BagportError(f"--codec {value}: must be a YAML mapping of encoder settings")
    return data


def _yaml_file(path: Path, what: str) -> Any:
    """A small YAML file's content; a file that cannot be read or parsed is one paragraph naming it."""
    return _yaml_source(path, what).data


def _yaml_source(path: Path, what: str) -> YamlSource:
    """A small YAML file with its lines (:func:`_yaml_file`)."""
    try:
        return load_yaml(path.read_text(encoding="utf-8"), str(path))  # a key given twice is refused
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or type(err).__name__
        raise BagportError(
            f"{what}: {path} is not valid YAML{where} ({problem}). Fix: correct the file."
        ) from err
    except UnicodeDecodeError as err:
        from bagport.uris import UTF8_FIX  # noqa: PLC0415 - fsspec with it: not on `--help`'s path

        raise BagportError(
            f"{what}: {path} is not UTF-8 text (the byte at offset {err.start} is not). Fix: {UTF8_FIX}"
        ) from err
    except OSError as err:
        raise BagportError(
            f"{what}: {path} cannot be read ({err.strerror or err}). Fix: check the path."
        ) from err


PRESETS: dict[str, Callable[[str | None], Any]] = {"codec": load_encoder}
"""A :class:`CliOption`'s ``named`` preset -> what loads it into its field (``codec`` -> ``encoder``)."""


def config_options(
    model: type[ConvertConfig] = ConvertConfig,
) -> Iterator[tuple[str, FieldInfo, CliOption]]:
    """``(field name, field, its command-line option)`` of every :class:`ConvertConfig` field, in order."""
    for name, field in model.model_fields.items():
        yield name, field, cli_option(name, field)


def _key(name: str, option: CliOption) -> str:
    """The option's argparse dest and run.yaml key: the field's name, or its preset's (``codec``)."""
    return option.named or name


def _value_type(annotation: Any) -> Any:
    """``annotation`` without ``| None`` and constraints (``PositiveInt | None`` -> ``int``)."""
    return _unwrap(annotation)[0]


def _unwrap(annotation: Any) -> tuple[Any, tuple[Any, ...]]:
    """``annotation`` without ``| None``, and its ``Annotated`` metadata (``PositiveInt`` -> ``Gt(0)``)."""
    if get_origin(annotation) in (Union, types.UnionType):
        (annotation,) = [a for a in get_args(annotation) if a is not type(None)]
    if get_origin(annotation) is Annotated:
        annotation, *metadata = get_args(annotation)
        return annotation, tuple(metadata)
    return annotation, ()


def number_type(kind: type[int] | type[float], *bounds: Any) -> Callable[[str], Any]:
    """An argparse ``type`` reading an ``int`` or ``float`` within ``bounds`` (annotated_types ``Gt``,
    ``Ge``, ``Le``), so a value out of range is refused by the parser, naming the option (``argument
    --workers: 0 is not allowed: give 1 or more``)."""
    above = _bound(bounds, annotated_types.Gt, "gt")
    strict = kind is float and above is not None  # more than 0.0; an int more than 0 is 1 or more
    low = _bound(bounds, annotated_types.Ge, "ge")
    if low is None and above is not None:
        low = above if strict else above + 1
    high = _bound(bounds, annotated_types.Le, "le")
    if low is not None and high is not None:
        allowed = f"{low} to {high}"
    elif low is not None:
        allowed = f"more than {low}" if strict else f"{low} or more"
    else:
        allowed = f"{high} or less"

    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a {_NUMBER[kind]}") from None
        too_low = low is not None and (value <= low if strict else value < low)
        if too_low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text} is not allowed: give {allowed}")
        return value

    return parse


def _bound(bounds: tuple[Any, ...], kind: type, name: str) -> int | float | None:
    """The number of the first ``kind`` constraint in ``bounds`` (``Gt(0)``, ``"gt"`` -> 0)."""
    for bound in bounds:
        value = getattr(bound, name, None) if isinstance(bound, kind) else None
        if isinstance(value, int | float):
            return value
    return None


_NUMBER = {int: "whole number", float: "number"}
POSITIVE_INT = number_type(int, annotated_types.Gt(0))
"""A count (``--workers``, ``--episodes``): 1 or more."""


def _comma_list(text: str) -> tuple[str, ...]:
    return tuple(part.strip() for part in text.split(",") if part.strip())


GIVEN = "config_options_given"
"""The namespace attribute listing the run options given on the command line (:class:`_Given`)."""


class _Given(argparse.Action):
    """Stores the option's value (a flag's ``const``) and records that it was given, so that a value equal
    to the default still overrides ``--config``'s."""

    def __call__(
        self, _parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, _flag: Any = None
    ) -> None:
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)
        setattr(namespace, GIVEN, {*getattr(namespace, GIVEN, ()), self.dest})


def _argument(name: str, field: FieldInfo, option: CliOption) -> dict[str, Any]:
    """``add_argument``'s keywords for the field: type, choices, default and metavar from its annotation."""
    default = None if field.is_required() else field.get_default(call_default_factory=False)
    if option.named:
        return {"default": None, "metavar": option.metavar}
    kind = _value_type(field.annotation)
    if kind is bool:
        if default is False:
            return {"action": _Given, "nargs": 0, "const": True, "default": False}
        return {"action": argparse.BooleanOptionalAction, "default": default}
    if get_origin(kind) is Literal:
        return {"choices": list(get_args(kind)), "default": default}
    if get_origin(kind) is tuple:  # given comma-separated
        text = None if default is None else ",".join(default)
        return {"type": _comma_list, "default": text, "metavar": option.metavar}
    bounds = [*_unwrap(field.annotation)[1], *field.metadata]
    if kind in (int, float) and any(isinstance(b, annotated_types.BaseMetadata) for b in bounds):
        return {"type": number_type(kind, *bounds), "default": default, "metavar": option.metavar}
    if kind in (str, int, float):
        return {"type": kind, "default": default, "metavar": option.metavar}
    raise TypeError(f"ConvertConfig.{name} ({kind}): no command-line form; give it a CliOption(named=...)")


def add_config_options(parser: argparse.ArgumentParser, model: type[ConvertConfig] = ConvertConfig) -> None:
    """One option per :class:`ConvertConfig` field: flag, type, choices and default from the field, help
    from its description; the fields of one :attr:`CliOption.group` mutually exclusive."""
    groups: dict[str, argparse._MutuallyExclusiveGroup] = {}
    for name, field, option in config_options(model):
        target = parser if option.group is None else groups.get(option.group)
        if target is None:
            target = groups[str(option.group)] = parser.add_mutually_exclusive_group()
        target.add_argument(
            str(option.flag),
            dest=_key(name, option),
            help=(field.description or "").replace("%", "%%"),  # argparse formats help with %
            **{"action": _Given, **_argument(name, field, option)},
        )


def resolve_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """Run options keyed as in ``run.yaml`` -> :class:`ConvertConfig`'s fields: a preset name loaded into
    its field (``codec`` -> ``encoder``), a comma-separated list split (``formats: lerobot,hdf5``)."""
    resolved = dict(options)
    for name, field, option in config_options():
        if option.named and option.named in resolved:
            resolved[name] = PRESETS[option.named](resolved.pop(option.named))
        elif get_origin(_value_type(field.annotation)) is tuple and isinstance(resolved.get(name), str):
            resolved[name] = _comma_list(resolved[name])
    return resolved


COMMAND_LINE_ONLY: dict[str, str] = {
    "config": "--config",
    "push_to_hub": "--push-to-hub",
    "private": "--private",
    "revision": "--revision",
    "exclude_provenance": "--exclude-provenance",
    "full_provenance": "--full-provenance",
    "quiet": "--quiet",
    "verbose": "--verbose",
}
"""``bagport convert``'s options about the command itself, not the run: no :class:`ConvertConfig` field, so
no key in a ``--config`` file or a deployment's ``config`` (the key one would write -> the flag to give)."""


def _config_file(path: str) -> dict[str, Any]:
    source = _yaml_source(Path(path), "--config") if Path(path).is_file() else None
    if source is None or not isinstance(source.data, dict):
        raise BagportError(
            f"--config {path}: not a YAML mapping of run options (or no such file). Fix: give a file such as "
            "'manifest: fleet.yaml\ncontract: robot.yaml\noutput: datasets/robot\nrunner: dask'."
        )
    _refuse_command_line_only(source, path)
    return dict(source.data)


def _refuse_command_line_only(source: YamlSource, path: str) -> None:
    """A key of :data:`COMMAND_LINE_ONLY` in the file is named, on its line, with the flag to give instead
    (the run's options would refuse it as an unknown field, with no hint)."""
    keys = [key for key in source.data if key in COMMAND_LINE_ONLY]
    if not keys:
        return
    flags = " ".join(COMMAND_LINE_ONLY[key] for key in keys)
    if len(keys) == 1:
        where, what, them = f", line {source.line_of(keys)}", f"{keys[0]} is a command-line option", "it"
    else:
        found = " and ".join(f"{key} (line {source.line_of((key,))})" for key in keys)
        where, what, them = "", f"{found} are command-line options", "them"
    raise BagportError(
        f"--config {path}{where}: {what} only (about the command, not the run: a run file has no such key). "
        f"Fix: remove {them} from the file and give {flags} on the command line."
    )


def convert_config(args: argparse.Namespace, defaults: dict[str, Any]) -> ConvertConfig:
    """The run's :class:`ConvertConfig`: the ``--config`` file's options, overridden by those given on the
    command line (given: recorded by the parser, or other than the parser's ``defaults``)."""
    options = _config_file(args.config) if args.config else {}
    given: set[str] = getattr(args, GIVEN, set())
    for name, _, option in config_options():
        key = _key(name, option)
        if key not in given and getattr(args, key) == defaults[key]:
            continue
        options[key] = getattr(args, key)
        for other, _, other_option in config_options():  # the command line's bag source replaces the file's
            if other != name and option.group is not None and other_option.group == option.group:
                options.pop(_key(other, other_option), None)
    return ConvertConfig(**resolve_options(options))
