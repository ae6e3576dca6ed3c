"""The ``bagport`` program's start: a ``convert``'s temporary Prefect server is launched before anything
heavy is imported, and a server the command never used is not left running."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import python_output

_ORDER_PROBE = """
import sys
events = []

class Watch:
    def find_spec(self, name, path=None, target=None):
        if name == "bagport.config":
            events.append("import-" + name)
        return None

sys.meta_path.insert(0, Watch())
import contextlib
import flows.cli
flows.cli.launch = lambda: events.append("launch")
try:
    with contextlib.redirect_stdout(sys.stderr):  # --help's text
        flows.cli.main(sys.argv[1:])
except SystemExit:
    pass
print(*(dict.fromkeys(events)))
"""


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        # the server first: the parser's defaults come from bagport's pydantic models
        (["convert", "--no-such-option"], ["launch", "import-bagport.config"]),
        (["convert", "--help"], ["import-bagport.config"]),  # no run: no server
        (["inspect", "--no-such-option"], ["import-bagport.config"]),
    ],
)
def test_a_convert_launches_its_server_before_the_parsers_imports(
    tmp_path: Path, argv: list[str], expected: list[str]
) -> None:
    assert python_output(_ORDER_PROBE.replace("sys.argv[1:]", repr(argv)), tmp_path / "home") == expected


_UNUSED_PROBE = """
import flows.cli, flows.local_server
servers = []
launch = flows.local_server.launch
def recorded():
    server = launch()
    servers.append(server)
    return server
flows.cli.launch = recorded
try:
    flows.cli.main(["convert", "--no-such-option"])
except SystemExit:
    pass
server = servers[0]
print(server is not None, server._process is None, flows.local_server.take_launched() is None)
"""


def test_a_convert_that_fails_before_its_run_leaves_no_server(tmp_path: Path) -> None:
    """A bad option ends the command in the parser, after the server was launched: it is killed then,
    not left to boot and serve until the process exits."""
    env = {"PREFECT_API_URL": ""}
    assert python_output(_UNUSED_PROBE, tmp_path / "home", **env) == ["True", "True", "True"]
