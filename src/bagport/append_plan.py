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

from bagport.bags import open_bag
from bagport.dataset.history import DatasetBags
from bagport.episode.checks import bag_fingerprint
from bagport.errors import BagportError
from bagport.manifest import BagEntry

__all__ = ["bags_to_append"]


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
