"""Which bags of a manifest an ``--append`` adds: those whose window the dataset does not hold yet.

A bag is known by its URI and its manifest window (``start_s``/``end_s``...): another window of a bag
in the dataset is a new episode. A bag whose files changed since it was appended (another source
stamp: a new modification time after a copy without ``-p``, a restore from a backup) is a new episode
only when it is another recording: its index (files, sizes, message counts, time range: the
fingerprint every episode's provenance records) differs. The same recording copied again is not
appended twice. A bag a run left out (failed QA or conversion) converts again once its files change.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from bagport.bags import open_bag
from bagport.config import ConvertConfig
from bagport.contract import ContractPlan, FeatureKind
from bagport.dataset.base import read_info
from bagport.dataset.history import DatasetBags
from bagport.dataset.layout import DEFAULT_FEATURES
from bagport.episode.checks import bag_fingerprint
from bagport.errors import BagportError, DatasetWriteError
from bagport.manifest import BagEntry
from bagport.video import EncoderSettings, stream_codec

__all__ = ["bags_to_append", "check_append_fits"]


def check_append_fits(config: ConvertConfig, contract: ContractPlan, *, adding: bool) -> int:
    """Before anything converts, an append ``adding`` bags whose contract or encoder would give other
    features than the dataset's ``meta/info.json`` is refused (the commit would refuse it after converting
    every bag): other keys, fps or robot type, or a camera the dataset encoded with other settings (the
    same keys the commit compares). A vector's shape and names are known from the bags only: the commit
    checks them. An append with nothing new writes nothing, and is not refused. The dataset's episodes."""
    info = read_info(config.output)
    differences = _differences(info, contract, EncoderSettings.from_dict(config.encoder)) if adding else []
    if not differences:
        return int(info["total_episodes"])
    raise DatasetWriteError(
        f"cannot append to {config.output} with {config.contract}: the contract or codec does not match the "
        f"dataset ({'; '.join(differences)}); nothing was converted. Fix: append with the contract and codec "
        "the dataset was made with, or convert into a new --output."
    )


def _differences(info: dict[str, Any], contract: ContractPlan, encoder: EncoderSettings) -> list[str]:
    have, features = sorted(set(info["features"]) - set(DEFAULT_FEATURES)), info["features"]
    want = sorted(f.key for f in contract.features)
    found = [f"fps: dataset {info['fps']}, contract {contract.fps}"] if info["fps"] != contract.fps else []
    robot_type = info.get("robot_type")
    if robot_type not in (None, contract.robot_type):  # info.json has one: it would relabel every episode
        found.append(f"robot_type: dataset {robot_type!r}, contract {contract.robot_type!r}")
    if only_dataset := [k for k in have if k not in want]:
        found.append(f"only in the dataset: {', '.join(only_dataset)}")
    if only_contract := [k for k in want if k not in have]:
        found.append(f"only in the contract: {', '.join(only_contract)}")
    asked = _asked_info(encoder)
    for feature in (f for f in contract.features if f.key in features):
        video = features[feature.key].get("info") or {}
        if feature.kind is not FeatureKind.VIDEO or video.get("is_depth_map"):
            continue
        if changed := [k for k, v in asked.items() if k in video and video[k] != v]:
            were = ", ".join(f"{k} {video[k]!r} -> {asked[k]!r}" for k in changed)
            found.append(f"{feature.key} encoder: {were}")
    return found


_FIRST = ("video.codec", "video.pix_fmt", "video.g")
"""The encoder keys a difference names first: the codec itself, then what a decoder sees most."""


def _asked_info(encoder: EncoderSettings) -> dict[str, Any]:
    """The keys ``encoder`` would write in a camera's ``info`` that an append compares, codec first
    (an encoder this PyAV build lacks has no codec to compare: starting it is refused with its own error)."""
    info = {**encoder.to_info(), "video.pix_fmt": encoder.pix_fmt}
    codec = stream_codec(encoder.codec)
    if codec is not None:
        info["video.codec"] = codec
    rank = {key: index for index, key in enumerate(_FIRST)}
    return {k: info[k] for k in sorted(info, key=lambda k: (rank.get(k, len(rank)), k))}


def bags_to_append(
    bags: tuple[BagEntry, ...],
    known: DatasetBags,
    stamp_of: Callable[[str], str],
    msg_definitions: Mapping[str, str],
) -> tuple[BagEntry, ...]:
    """The bags (manifest entries) the dataset described by ``known`` does not hold yet."""
    return tuple(b for b in bags if _is_new(b, known, stamp_of, msg_definitions))


def _is_new(
    bag: BagEntry, known: DatasetBags, stamp_of: Callable[[str], str], msg_definitions: Mapping[str, str]
) -> bool:
    window, stamp = bag.window.key(), stamp_of(bag.uri)
    appended = known.kept_as(bag.uri, window)
    if appended is None:
        return not known.left_out_unchanged(bag.uri, window, stamp)
    if stamp in appended:
        return False
    recorded = set(appended.values()) - {""}
    return bool(recorded) and _fingerprint(bag.uri, msg_definitions) not in recorded


def _fingerprint(uri: str, msg_definitions: Mapping[str, str]) -> str | None:
    """The bag's index fingerprint; ``None`` when it cannot be opened (its conversion says why)."""
    try:
        with open_bag(uri, msg_definitions=msg_definitions) as reader:
            return bag_fingerprint(reader.info)
    except BagportError:
        return None
