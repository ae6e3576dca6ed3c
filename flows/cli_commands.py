"""The ``bagport`` commands other than ``convert``: inspect, qa, validate, repair, contract check/init, synth.

Each handler takes the parsed arguments and returns the exit code; :func:`flows.cli.build_parser` wires
them to their subcommands. bagport's modules are imported inside each handler, so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = [
    "cmd_contract_check",
    "cmd_contract_init",
    "cmd_inspect",
    "cmd_qa",
    "cmd_repair",
    "cmd_synth",
    "cmd_validate",
    "msg_definitions",
]


def msg_definitions(args: argparse.Namespace) -> dict[str, str]:
    from bagport.bags import read_msg_path  # noqa: PLC0415 - keep `--help` fast

    return read_msg_path(args.msg_path) if args.msg_path else {}


def cmd_inspect(args: argparse.Namespace) -> int:
    from bagport.bags import format_bag_info, open_bag  # noqa: PLC0415 - keep `--help` fast

    definitions = msg_definitions(args)
    for uri in args.uri:
        with open_bag(uri, msg_definitions=definitions) as reader:
            print(format_bag_info(reader.info))
            read = reader.transfer
            if read.access != "local":
                print(
                    f"Read:              {read.access}, {read.bytes_read} bytes in {read.requests} requests"
                )
            for topic, msgtype in sorted(reader.undefined_types.items()):
                print(f"  type defined nowhere: {topic} ({msgtype}); give its .msg with --msg-path DIR")
    return 0


def cmd_qa(args: argparse.Namespace) -> int:
    from bagport.episode.score import score_manifest  # noqa: PLC0415
    from bagport.qa import episode_ref  # noqa: PLC0415

    entries = score_manifest(
        args.manifest,
        args.contract,
        args.qa,
        workers=args.workers,
        msg_definitions=msg_definitions(args),
        keep_failed=args.keep_failed,
    )
    for entry in entries:
        qa = entry.qa
        where = episode_ref(qa.bag_uri, entry.segment)
        label = f" ({entry.label})" if entry.label else ""
        reason = f"excluded: {entry.excluded_reason}" if entry.by_label else qa.headline()
        print(f"{qa.verdict:4s} {qa.score:.2f}  bags[{entry.manifest_entry}] {where}{label}: {reason}")
    if args.report:
        from bagport.qa.report import render_report  # noqa: PLC0415

        _write_report(
            args.report,
            render_report(
                entries,
                {
                    "manifest": args.manifest,
                    "contract": args.contract,
                    "bags": len({e.manifest_entry for e in entries}),
                    "episodes": len(entries),
                },
            ),
        )
        print(f"report: {args.report}", file=sys.stderr)
    # episodes left out for their label (failed / discarded demonstrations) do not fail the command
    scored = [e for e in entries if not e.by_label]
    failing = sum(e.qa.verdict == "fail" for e in scored)
    unit = "bag(s)" if all(e.segment is None for e in entries) else "episode(s)"
    labelled = (
        f" ({len(entries) - len(scored)} more excluded for their label)" if len(scored) < len(entries) else ""
    )
    print(f"{len(scored) - failing} of {len(scored)} {unit} pass QA{labelled}", file=sys.stderr)
    return 1 if failing else 0


def cmd_validate(args: argparse.Namespace) -> int:
    from bagport.dataset.validate import validate_dataset  # noqa: PLC0415

    def progress(done: int, total: int) -> None:
        if done == total or done % 200 == 0:
            print(f"\rdecoded {done}/{total} frames", end="", file=sys.stderr, flush=True)

    # a count redrawn in place on a terminal only: in a job's log each redraw would be one run-on line
    on_terminal = sys.stderr.isatty()
    report = validate_dataset(
        args.root, repo_id=args.repo_id, decode_every=args.every, progress=progress if on_terminal else None
    )
    if on_terminal:
        print(file=sys.stderr)
    print(
        f"OK {report.root}: {report.episodes} episode(s), {report.frames} frames, "
        f"{report.frames_decoded} decoded through LeRobot ({report.video_backend}); videos: "
        f"{', '.join(report.video_keys) or 'none'}; {report.files_checked} file(s) match their SHA-256"
    )
    return 0


def cmd_repair(args: argparse.Namespace) -> int:
    from fsspec.core import url_to_fs  # noqa: PLC0415

    from bagport.dataset.repair import repair_dataset  # noqa: PLC0415

    report = repair_dataset(args.output, clean_scratch=True)
    for action in report.actions:
        print(action)
    fs, path = url_to_fs(args.output)
    if not report.actions and not fs.exists(path):  # a mistyped path: not "nothing to repair"
        print(
            f"bagport repair: {args.output} does not exist, so there is nothing there to repair. Fix: give the "
            "dataset's folder or URI as given to convert --output.",
            file=sys.stderr,
        )
        return 2
    if not report.actions:
        print(f"{args.output}: nothing to repair")
    return 0


def cmd_contract_check(args: argparse.Namespace) -> int:
    from bagport.contract import load_contract  # noqa: PLC0415
    from bagport.feature_table import describe_features, format_feature_table  # noqa: PLC0415

    plan = load_contract(args.contract)
    bags = args.bag or [None]
    definitions = msg_definitions(args)
    for bag in bags:
        rows = describe_features(plan, bag, definitions)
        print(f"{args.contract}" + (f" against {bag}" if bag else "") + ": OK")
        print(format_feature_table(plan, rows))
    return 0


def cmd_contract_init(args: argparse.Namespace) -> int:
    from bagport.bags import open_bag  # noqa: PLC0415
    from bagport.contract.draft import draft_contract_from_bag  # noqa: PLC0415
    from bagport.errors import BagportError  # noqa: PLC0415

    with open_bag(args.bag, msg_definitions=msg_definitions(args)) as reader:
        text = draft_contract_from_bag(reader, robot_type=args.robot_type, fps=args.fps)
    if args.out:
        out = Path(args.out)
        if out.exists():
            raise BagportError(f"{out} already exists; nothing was written. Fix: choose another --out.")
        out.write_text(text)
        print(f"wrote {out}", file=sys.stderr)
    else:
        print(text, end="")
    return 0


def cmd_synth(args: argparse.Namespace) -> int:
    from bagport.synth import write_sample_fleet  # noqa: PLC0415

    paths = write_sample_fleet(
        Path(args.out), episodes=args.episodes, duration_s=args.duration, seed=args.seed
    )
    for path in paths:
        print(path)
    print(f"wrote {len(paths)} bag(s) and {Path(args.out) / 'manifest.yaml'}", file=sys.stderr)
    return 0


def _write_report(path: str, html: str) -> None:
    """The QA report at ``path``; a path that cannot be written is one paragraph (the scores printed above
    stand)."""
    from bagport.errors import BagportError  # noqa: PLC0415 - keep `--help` fast

    try:
        Path(path).write_text(html, encoding="utf-8")
    except OSError as err:
        raise BagportError(
            f"--report {path}: cannot be written ({err.strerror or err}); the scores above are complete. Fix: "
            "give a path in a folder that exists and you can write to."
        ) from err
