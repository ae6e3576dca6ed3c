"""A conversion run as library calls: plan the episodes, then reduce staged results.

The orchestration (fan-out, retries, runners) lives in ``flows/``; these
functions are what it calls before and after the per-episode map.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import fsspec
from fsspec.core import url_to_fs

from bagport import __version__
from bagport.config import ConvertConfig
from bagport.contract import ContractPlan, parse_contract
from bagport.dataset import DatasetLimits, DatasetReport, write_dataset
from bagport.episode import EpisodeRequest, episode_id_for
from bagport.errors import ContractError, DatasetWriteError
from bagport.manifest import Manifest, load_manifest
from bagport.staging import EpisodeSummary, read_summary
from bagport.video import EncoderSettings

__all__ = ["RunPlan", "plan_run", "reduce_run"]


@dataclass(frozen=True, slots=True)
class RunPlan:
    config: ConvertConfig
    contract: ContractPlan
    manifest: Manifest
    requests: tuple[EpisodeRequest, ...]
    contract_text: str


def _read(uri: str, what: str) -> str:
    try:
        with fsspec.open(uri, "r", encoding="utf-8") as handle:
            return str(handle.read())
    except FileNotFoundError as err:
        raise ContractError(f"{what} file does not exist", file=uri, fix=f"check the --{what} path.") from err


def plan_run(config: ConvertConfig) -> RunPlan:
    """Validate the manifest, contract and encoder settings; one request per bag.

    Everything that can be checked without reading bags is checked here, before
    any work starts, and the output must not exist unless ``overwrite``.
    """
    contract_text = _read(config.contract, "contract")
    contract = parse_contract(contract_text, config.contract)
    EncoderSettings.from_dict(config.encoder)
    manifest = load_manifest(config.manifest)
    fs, out_path = url_to_fs(config.output)
    if fs.exists(out_path) and not config.overwrite:
        raise DatasetWriteError(
            f"{config.output} already exists; nothing was written. Fix: choose a new --output, or pass "
            "--overwrite to replace it (the old dataset stays until the new one is complete)."
        )
    staging = config.resolved_staging()
    requests = tuple(
        EpisodeRequest(
            episode_id=episode_id_for(bag.uri, contract_text, config.encoder),
            bag_uri=bag.uri,
            manifest_entry=bag.entry,
            staging_uri=staging,
            contract_text=contract_text,
            contract_name=config.contract,
            encoder=dict(config.encoder),
            default_task=bag.task,
            metadata=bag.metadata,
        )
        for bag in manifest.bags
    )
    return RunPlan(config, contract, manifest, requests, contract_text)


def run_record(plan: RunPlan) -> dict[str, Any]:
    return {
        "bagport_version": __version__,
        "repo_id": plan.config.resolved_repo_id(),
        "contract": {"uri": plan.config.contract, "text": plan.contract_text},
        "manifest": {"uri": plan.config.manifest, "bags": [b.uri for b in plan.manifest.bags]},
        "encoder": EncoderSettings.from_dict(plan.config.encoder).to_info(),
        "host_cpus": os.cpu_count(),
    }


def reduce_run(plan: RunPlan, staged_dirs: Sequence[str]) -> DatasetReport:
    """Read the staged summaries (in manifest order) and write the dataset."""
    summaries: list[EpisodeSummary] = []
    for uri in staged_dirs:
        summary = read_summary(uri)
        if summary is None:
            raise DatasetWriteError(
                f"staged episode {uri} is incomplete (no episode.json); re-run the conversion."
            )
        summaries.append(summary)
    limits = DatasetLimits(
        chunks_size=plan.config.chunks_size,
        data_files_size_in_mb=plan.config.data_files_size_in_mb,
        video_files_size_in_mb=plan.config.video_files_size_in_mb,
    )
    report = write_dataset(
        summaries,
        plan.config.output,
        robot_type=plan.contract.robot_type,
        limits=limits,
        run_record=run_record(plan),
        overwrite=plan.config.overwrite,
    )
    if not plan.config.keep_staging:
        fs, path = url_to_fs(plan.config.resolved_staging())
        for uri in staged_dirs:
            _, episode_path = url_to_fs(uri)
            if fs.exists(episode_path):
                fs.rm(episode_path, recursive=True)
        try:
            if fs.exists(path) and not fs.find(path):
                fs.rm(path, recursive=True)
        except OSError:
            pass
    return report


def summary_json(report: DatasetReport) -> str:
    return json.dumps(
        {
            "root": report.root,
            "episodes": report.episodes,
            "frames": report.frames,
            "duration_s": round(report.duration_s, 3),
            "tasks": list(report.tasks),
            "videos": list(report.video_keys),
            "size_bytes": report.size_bytes,
        },
        indent=2,
    )
