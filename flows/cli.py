"""The ``bagport`` command line.

Errors bagport raises on purpose (``BagportError``) print as one paragraph with
exit code 2; nothing prints a traceback unless ``BAGPORT_DEBUG=1``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from flows import cli_commands
from flows.console import outlive_closed_output, say_when_terminated
from flows.local_server import launch, take_launched

if TYPE_CHECKING:
    import pydantic

    from bagport.config import ConvertConfig
    from bagport.dataset import DatasetReport
    from bagport.errors import BagportError
    from bagport.run import RunPlan

__all__ = ["build_parser", "main"]


def _progress_bar(done: int, total: int) -> None:
    width = 30
    filled = width * done // max(total, 1)
    # the reduce follows the last episode (seconds for a fleet's thousands): the bar says so, not a stall
    then = "; writing the dataset ..." if done >= total else ""
    print(
        f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{total} episodes{then}",
        end="",
        file=sys.stderr,
        flush=True,
    )


def _cmd_convert(args: argparse.Namespace) -> int:
    # the temporary Prefect server (main() launched it before the parser's imports) boots while the imports
    # below run; main() kills it if the run ends without using it
    server = launch()
    # something from the first second (start-up takes 5-13 s)
    starting = not args.quiet and sys.stderr.isatty()
    if starting:
        print("starting: planning ...", end="", file=sys.stderr, flush=True)  # the bar overwrites it
    try:
        return _convert(args, throwaway_api=server is not None)
    except BaseException:
        if starting:  # the error's paragraph starts its own line: the "starting" text erased, if still there
            print("\r\x1b[K", end="", file=sys.stderr, flush=True)
        raise


def _option_errors(err: pydantic.ValidationError) -> str:
    """Pydantic's findings about the options, one clause each, without its URLs; a missing option named
    as the user gives it (its flag, or its key in --config)."""
    from bagport.config import ConvertConfig, cli_option  # noqa: PLC0415

    fields = ConvertConfig.model_fields
    clauses = []
    for item in err.errors():
        where = ".".join(str(part) for part in item["loc"])
        message = item["msg"].removeprefix("Value error, ")
        if item["type"] == "missing" and where in fields:
            flag = cli_option(where, fields[where]).flag
            message = f"required: give {flag} (or {where}: in a --config file)"
        clauses.append(f"{where}: {message}" if where else message)
    return "; ".join(clauses)


def _convert(args: argparse.Namespace, *, throwaway_api: bool = False) -> int:
    """Convert. With ``throwaway_api`` (a temporary Prefect server, which nobody watches after the run), a
    run whose dataset is up to date, or an append with nothing new, finishes here without Prefect:
    nothing to convert, write or record, so neither a flow run nor the server's boot is waited for."""
    from flows.import_gc import paused  # noqa: PLC0415 - standard library only

    with paused():  # the heavy imports (flows/import_gc.py)
        import pydantic  # noqa: PLC0415

        from bagport.errors import BagportError  # noqa: PLC0415
        from bagport.hub.push import check_repo_id  # noqa: PLC0415
        from bagport.qa import episode_ref  # noqa: PLC0415
        from bagport.reduce import finish_nothing_new, finish_up_to_date, summary_json  # noqa: PLC0415
        from bagport.run import plan_run, up_to_date  # noqa: PLC0415
        from flows.cli_config import convert_config  # noqa: PLC0415
        from flows.cli_push import hf_token, push_from_args  # noqa: PLC0415

    try:
        config = convert_config(args, vars(build_parser().parse_args(["convert"])))
    except pydantic.ValidationError as err:
        raise BagportError(f"invalid options: {_option_errors(err)}") from err
    if args.push_to_hub and (
        config.repo_id is None or "lerobot" not in config.formats or "://" in config.output
    ):
        raise BagportError(
            "--push-to-hub publishes the local LeRobot dataset under --repo-id: give --repo-id ORG/NAME (or "
            "repo_id: in the --config file), keep lerobot in --format and a local --output (push one on an "
            "object store from a local copy)"
        )
    if args.push_to_hub:  # before converting, not after
        check_repo_id(config.resolved_repo_id())
        hf_token()
    started = time.perf_counter()
    show_bar = not args.quiet and sys.stderr.isatty()
    plan = plan_run(config)  # bad manifests, contracts and outputs fail here, before Prefect starts
    if plan.staging_removed:
        print(plan.staging_note(), file=sys.stderr)
    for overlap in plan.overlaps:
        print(f"warning: {overlap.note()}", file=sys.stderr)
    if throwaway_api and (plan.up_to_date or (not plan.requests and not plan.reused)):
        # up to date, or an append with nothing new
        report = finish_up_to_date(plan) if plan.up_to_date else finish_nothing_new(plan)
        if show_bar:
            print(file=sys.stderr)  # ends the "starting" line
    else:
        report = _run_flow(
            config, plan, show_bar, server_up=not throwaway_api, fork_cli=getattr(args, "as_program", False)
        )
    if not args.quiet:
        print(summary_json(report))
    for fmt, output in report.outputs.items():
        if output != report.root:
            print(f"wrote {fmt} at {output}", file=sys.stderr)
    wall_s = time.perf_counter() - started
    for row in report.excluded:
        print(
            f"excluded bags[{row.manifest_entry}] {episode_ref(row.bag_uri, row.segment)}: {row.reason}",
            file=sys.stderr,
        )
    print(_summary_line(report, args.append, wall_s), file=sys.stderr)
    if args.push_to_hub:
        push_from_args(report.outputs.get("lerobot", report.root), config.resolved_repo_id(), args)
    # episodes left out for their label (failed / discarded demonstrations) are not a problem of the run, nor
    # are the failed bags of an up-to-date dataset (reported by the run that wrote it, unchanged since)
    return 1 if not up_to_date(report) and any(not row.excluded_by_label for row in report.excluded) else 0


def _run_flow(
    config: ConvertConfig, plan: RunPlan, show_bar: bool, *, server_up: bool, fork_cli: bool
) -> DatasetReport:
    """Run the flow; ``server_up``: against a configured Prefect API (no temporary server boots).
    ``fork_cli``: this process is the ``bagport`` program (not a caller of :func:`main`, such as a test
    or a script), so the pool's forkserver can be a fork of it (:func:`flows.forkserver.start`)."""
    from flows import forkserver  # noqa: PLC0415 - standard library only
    from flows.import_gc import paused  # noqa: PLC0415 - standard library only

    warm = config.on_local_pool() and bool(plan.requests)
    if server_up and warm:
        # The flow starts as soon as Prefect is imported: the workers' imports begin now, beside those,
        # or its first task runs wait for them (0.65 s on W3).
        forkserver.start(fork_this_process=fork_cli)
    with paused():
        from flows.artifacts import LISTENERS  # noqa: PLC0415 - imports Prefect
        from flows.convert import run_convert  # noqa: PLC0415 - imports Prefect

    if warm and not server_up:  # with a temporary server, now: a fork of this process, with these imports
        forkserver.start(fork_this_process=fork_cli)
    if show_bar:
        LISTENERS.append(_progress_bar)
    try:
        return run_convert(config, plan)
    finally:
        if show_bar:
            LISTENERS.remove(_progress_bar)
            print(file=sys.stderr)


def _summary_line(report: DatasetReport, append: bool, wall_s: float) -> str:
    """One line: what this run wrote (reused, warned) and left out, or that it had nothing to do."""
    from bagport.run import up_to_date  # noqa: PLC0415

    if up_to_date(report):
        failed = (
            f", {len(report.excluded)} bag(s) that failed to convert before and are unchanged not tried again"
            if report.excluded
            else ""
        )
        return (
            f"up to date: {len(report.reused)} episode(s) reused{failed}, nothing to write at {report.root} "
            f"(its run record has this run's write key; {report.episodes} episode(s), {report.duration_s:.1f} s "
            f"of recordings); checked in {wall_s:.1f} s"
        )
    if append and not report.converted and not report.reused and not report.excluded:
        return (
            f"nothing to do: every bag is in {report.root} already, or was left out of it by an earlier run and "
            f"is unchanged since ({report.episodes} episode(s), {report.duration_s:.1f} s of recordings); checked "
            f"in {wall_s:.1f} s"
        )
    from flows.run_story import RunCounts  # noqa: PLC0415 - imports Prefect

    qa_report = f"; QA report: {report.root.rstrip('/')}/{report.qa_report}" if report.qa_report else ""
    counts = RunCounts.of(report)  # this run's episodes, not the dataset's (an append holds more)
    return (
        f"this run: {counts.text()} in {wall_s:.1f} s wall time; the dataset holds {report.episodes} "
        f"episode(s), {report.duration_s:.1f} s of recordings{qa_report}"
    )


def _install_crash_hook() -> None:
    """Test-only: ``BAGPORT_CRASH_AT=<step>`` SIGKILLs the process right after that commit step
    (see :mod:`bagport.dataset.crashpoints`); the library itself reads no environment."""
    step = os.environ.get("BAGPORT_CRASH_AT")
    if step:
        from bagport.dataset.crashpoints import kill_after, set_hook  # noqa: PLC0415

        set_hook(kill_after(step))


def build_parser() -> argparse.ArgumentParser:
    """The `bagport` argument parser (:mod:`flows.cli_parser`) with this module's command handlers."""
    handlers = {
        "convert": _cmd_convert,
        "qa": cli_commands.cmd_qa,
        "inspect": cli_commands.cmd_inspect,
        "validate": cli_commands.cmd_validate,
        "repair": cli_commands.cmd_repair,
        "contract check": cli_commands.cmd_contract_check,
        "contract init": cli_commands.cmd_contract_init,
        "synth": cli_commands.cmd_synth,
    }
    from flows import cli_parser  # noqa: PLC0415 - after a convert's temporary server is launched (main)

    return cli_parser.build_parser(handlers, _version())


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    try:
        return version("bagport")
    except PackageNotFoundError:  # a source tree without the package installed
        from bagport import __version__  # noqa: PLC0415

        return __version__


def _episodes_failed(err: BagportError) -> bool:
    """Exit code 1 (not 2): the input was fine, but episodes failed QA or conversion as configured."""
    from bagport.errors import QualityError  # noqa: PLC0415

    return isinstance(err, QualityError)  # by type: the error crossed the flow as the state's data


def _set_logging_env(*, verbose: bool, quiet: bool) -> None:
    """Prefect's log levels for this process and the ones it starts, before Prefect is imported."""
    if verbose:
        os.environ["PREFECT_LOGGING_LEVEL"] = "INFO"  # task and flow logs
    elif quiet:
        os.environ["PREFECT_LOGGING_LEVEL"] = "ERROR"
    else:
        os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    # Prefect's console lines repeat what bagport prints once (a failing bag's message came 4-6 times);
    # they still reach the API (the UI's run logs). --verbose shows them (set, not defaulted: an earlier
    # in-process call may have turned them off in this environment, and child processes inherit it).
    if verbose:
        os.environ["PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL"] = "INFO"
    else:
        os.environ.setdefault("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "CRITICAL")


def _launch_for_convert(argv: Sequence[str]) -> None:
    """A ``convert`` command's temporary Prefect server (:func:`flows.local_server.launch`), started before
    the parser's imports (0.1-0.3 s: its defaults come from bagport's pydantic models), as its boot is
    what the run waits for first. The server's log levels follow ``--verbose``/``--quiet`` as written."""
    if not argv or argv[0] != "convert" or {"-h", "--help"} & set(argv):
        return
    _set_logging_env(verbose="--verbose" in argv, quiet="--quiet" in argv)
    launch()


def main(argv: Sequence[str] | None = None) -> int:
    """The ``bagport`` program (``argv`` ``None``: the command line's), or a call of it from Python."""
    if argv is None:  # the program: a closed stdout or stderr must not stop its run (flows/console.py)
        outlive_closed_output()
        if sys.argv[1:2] == ["convert"]:
            say_when_terminated()
    _launch_for_convert(sys.argv[1:] if argv is None else list(argv))
    try:
        return _run_command(build_parser().parse_args(argv), as_program=argv is None)
    finally:
        unused = take_launched()  # a command that failed (or had nothing to do) before it used the server
        if unused is not None:
            unused.stop(graceful=False)  # it served nothing: no waiting for its start-up to finish


def _run_command(args: argparse.Namespace, *, as_program: bool) -> int:
    from bagport.errors import BagportError  # noqa: PLC0415 - after a convert's server is launched (main)

    args.as_program = as_program  # a process of its own: the pool's forkserver may be a fork of it
    _set_logging_env(verbose=getattr(args, "verbose", False), quiet=getattr(args, "quiet", False))
    func: Callable[[argparse.Namespace], int] = args.func
    _install_crash_hook()
    try:
        return func(args)
    except BagportError as err:
        if os.environ.get("BAGPORT_DEBUG") == "1":
            raise
        print(f"bagport {args.command}: error: {err}", file=sys.stderr)
        return 1 if _episodes_failed(err) else 2
    except KeyboardInterrupt:
        print(f"bagport {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
