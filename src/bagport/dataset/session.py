"""Opening a dataset write: recover the output, decide the base and the file plan, and hold a build
location for the file writers until the commit (:mod:`bagport.dataset.commit`) puts it in place.

The build location is the ``.X.tmp-<hex>`` folder beside a local output (locked by the process that
opened the write while it lives, :mod:`bagport.dataset.publish`), or on an object store the
``<root>/.bagport-staged-<hex>/`` prefix of the intent record (:mod:`bagport.dataset.remote`), which
is recorded (state ``staged``) before any file is uploaded there: a crash at any point before the
commit leaves only what recovery drops.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from fsspec.core import url_to_fs

from bagport.dataset.base import DatasetBase, read_base
from bagport.dataset.crashpoints import reached
from bagport.dataset.files import FilePlan, plan_files, staged_clip_sizes, staged_data_sizes
from bagport.dataset.journal import Journal, write_journal
from bagport.dataset.layout import STAGED_DIR
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.publish import building_beside
from bagport.dataset.remote import drop_staged
from bagport.dataset.repair import repair_dataset
from bagport.dataset.replace import refuse_existing
from bagport.errors import DatasetWriteError
from bagport.staging import EpisodeSummary, StagedFeature
from bagport.uris import is_local

__all__ = ["WriteSession", "check_consistent", "open_write"]


@dataclass(frozen=True, slots=True)
class WriteSession:
    """A write in progress (small and serialisable: it travels to the file writers and the commit)."""

    output: str
    build: str
    """Where the file writers put their files: a local build folder, or an object-store prefix."""
    plan: FilePlan
    features: tuple[StagedFeature, ...]
    mode: Literal["publish", "append"]
    remote: bool
    base: DatasetBase | None = None
    """What an append adds to, read once when the write opened (the commit checks it did not change)."""
    overwrite: bool = False
    """Whether the write may replace a dataset at the output (``--overwrite``); without it, one that another
    run put there while this one wrote is refused at the commit, never replaced."""

    @property
    def staged(self) -> str:
        """The build location's name relative to the output's parent (local) or root (object store)."""
        return self.build.rstrip("/").rsplit("/", 1)[-1]


def check_consistent(summaries: Sequence[EpisodeSummary]) -> tuple[StagedFeature, ...]:
    """The features every episode shares; a clear error for the first one that differs."""
    if not summaries:
        raise DatasetWriteError("no episode to write: every bag failed or the manifest is empty.")
    reference = summaries[0]
    for summary in summaries[1:]:
        if summary.fps != reference.fps:
            raise DatasetWriteError(
                f"{summary.bag_uri} was converted at {summary.fps} fps, {reference.bag_uri} at {reference.fps}"
            )
        mine = {f.key: f for f in summary.features}
        for feature in reference.features:
            other = mine.get(feature.key)
            if other is None:
                raise DatasetWriteError(
                    f"{summary.bag_uri} has no feature {feature.key!r} but {reference.bag_uri} has"
                )
            if (other.dtype, other.shape, other.names) != (feature.dtype, feature.shape, feature.names):
                raise DatasetWriteError(
                    f"feature {feature.key!r} differs between bags: {reference.bag_uri} gives "
                    f"{feature.dtype}{list(feature.shape)} names={feature.names}, {summary.bag_uri} gives "
                    f"{other.dtype}{list(other.shape)} names={other.names}. Fix: select the same joints/fields "
                    "explicitly with selector.names, and set image.resize so every camera has one size."
                )
            if feature.video_info != other.video_info:
                raise DatasetWriteError(
                    f"video {feature.key!r} was encoded differently in {summary.bag_uri} and {reference.bag_uri} "
                    f"({other.video_info} vs {feature.video_info}); clips can only be joined with identical settings."
                )
    return reference.features


def _plan(
    summaries: Sequence[EpisodeSummary],
    features: Sequence[StagedFeature],
    limits: DatasetLimits,
    base: DatasetBase | None,
) -> FilePlan:
    known = base.tasks if base is not None else []
    tasks = list(dict.fromkeys([*known, *(t for s in summaries for t in s.tasks)]))
    sizes = staged_clip_sizes(summaries, [f.key for f in features if f.video_info is not None])
    data_sizes = staged_data_sizes(summaries)
    if base is None:
        return plan_files(summaries, features, tasks, limits, sizes, data_sizes)
    return plan_files(
        summaries,
        features,
        tasks,
        DatasetLimits.from_info(base.info),
        sizes,
        data_sizes,
        next_data=base.next_data,
        next_video=base.next_video,
        first_episode=base.episodes,
        first_index=base.frames,
    )


@contextmanager
def open_write(
    summaries: Sequence[EpisodeSummary],
    output: str,
    *,
    limits: DatasetLimits | None = None,
    overwrite: bool = False,
    append: bool = False,
    repaired: bool = False,
    expect_episodes: int | None = None,
) -> Iterator[WriteSession]:
    """Repair ``output`` (unless the caller did already in this run: ``repaired``), plan the files, and
    hold a build location while the block runs; whatever the block did not commit is removed when it
    ends (see the module docstring). ``expect_episodes``: the episodes an append found in the dataset when
    it decided which bags were new; another number means another run wrote to it since, and the write is
    refused (the commit refuses one that happens later)."""
    fs, out_path = url_to_fs(output)
    if not repaired:
        repair_dataset(output)  # once per write: the commit does not repair again
    fs.invalidate_cache()
    features = check_consistent(summaries)
    appending = append and bool(fs.exists(out_path))
    base = read_base(output) if appending else None
    if base is None:
        refuse_existing(output, overwrite=overwrite)
    held = base.episodes if base is not None else 0
    if expect_episodes is not None and held != expect_episodes:
        raise DatasetWriteError(
            f"{output} changed since this run was planned (it held {expect_episodes} episode(s), now "
            f"{held}): another run wrote to it meanwhile, and may have "
            "appended this run's bags already; nothing was written. Fix: run the append again (it adds only what "
            "is still new, reusing the staged episodes); one run at a time per output."
        )
    plan = _plan(summaries, features, limits or DatasetLimits(), base)
    mode: Literal["publish", "append"] = "append" if appending else "publish"
    if is_local(fs):
        with building_beside(Path(out_path)) as build:
            yield WriteSession(
                output, str(build), plan, features, mode, remote=False, base=base, overwrite=overwrite
            )
        return
    root = out_path.rstrip("/")
    staged = STAGED_DIR.format(run_id=uuid.uuid4().hex[:8])
    write_journal(fs, root, Journal(op=mode, staged=staged, files=()))
    reached("s3.journaled")
    try:
        yield WriteSession(
            output, fs.unstrip_protocol(f"{root}/{staged}"), plan, features, mode,
            remote=True, base=base, overwrite=overwrite,
        )  # fmt: skip
    except Exception:  # a failure, not a kill (that is left to recovery): nothing of this write stays
        drop_staged(output, staged)
        raise
    drop_staged(output, staged)  # a block that ended without committing (after a commit: nothing to drop)
