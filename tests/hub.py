"""A small fake of the Hugging Face Hub's HTTP API on loopback, for the real ``huggingface_hub`` client
(``HF_ENDPOINT=http://127.0.0.1:PORT``). It answers the calls a dataset push makes (create repo, branch,
validate the card's YAML, preupload, commit, delete and create a tag) and records what it was sent: the
repos, the committed files and their contents, the tags, every request. It cannot prove the Hub itself:
it accepts every file as a regular (non-LFS) upload and checks no permission."""

from __future__ import annotations

import base64
import json
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import unquote

__all__ = ["FakeHub", "fake_hub"]

_REPO = r"/api/datasets/(?P<repo>[^/]+/[^/]+)"


@dataclass
class FakeHub:
    endpoint: str = ""
    repos: dict[str, dict[str, Any]] = field(default_factory=dict)
    """repo id -> the create request's body."""
    files: dict[str, dict[str, bytes]] = field(default_factory=dict)
    """``repo@branch`` -> path -> content, over every commit."""
    tags: dict[str, dict[str, str]] = field(default_factory=dict)
    """repo id -> tag -> branch it points at."""
    branches: dict[str, set[str]] = field(default_factory=dict)
    requests: list[tuple[str, str, dict[str, str], bytes]] = field(default_factory=list)
    """Every request: method, path, headers, body."""
    unknown: list[str] = field(default_factory=list)

    def handle(self, method: str, path: str, body: bytes) -> tuple[int, dict[str, str], Any]:
        route = unquote(path.split("?", 1)[0])
        if method == "POST" and route == "/api/repos/create":
            data = json.loads(body)
            repo = f"{data['organization']}/{data['name']}" if data.get("organization") else data["name"]
            self.repos[repo] = data
            self.branches.setdefault(repo, {"main"})
            return 200, {}, {"url": f"{self.endpoint}/datasets/{repo}", "name": repo}
        if method == "POST" and route == "/api/validate-yaml":
            return 200, {}, {"warnings": [], "errors": []}
        if (match := re.fullmatch(_REPO + r"/branch/(?P<branch>.+)", route)) and method == "POST":
            self.branches.setdefault(match["repo"], {"main"}).add(match["branch"])
            return 200, {}, {}
        if (match := re.fullmatch(_REPO + r"/preupload/(?P<rev>.+)", route)) and method == "POST":
            files = json.loads(body)["files"]
            return (
                200,
                {},
                {
                    "files": [
                        {"path": f["path"], "uploadMode": "regular", "shouldIgnore": False} for f in files
                    ]
                },
            )
        if (match := re.fullmatch(_REPO + r"/commit/(?P<rev>.+)", route)) and method == "POST":
            return self._commit(match["repo"], match["rev"], body)
        if (match := re.fullmatch(_REPO + r"/tag/(?P<tag>.+)", route)) and method == "DELETE":
            if self.tags.get(match["repo"], {}).pop(match["tag"], None) is None:
                return 404, {"X-Error-Code": "RevisionNotFound"}, {"error": "Invalid rev id"}
            return 200, {}, {}
        if (match := re.fullmatch(_REPO + r"/tag/(?P<rev>.+)", route)) and method == "POST":
            self.tags.setdefault(match["repo"], {})[json.loads(body)["tag"]] = match["rev"]
            return 200, {}, {}
        self.unknown.append(f"{method} {path}")
        return 404, {"X-Error-Code": "EntryNotFound"}, {"error": f"fake hub: no route {method} {route}"}

    def _commit(self, repo: str, revision: str, body: bytes) -> tuple[int, dict[str, str], Any]:
        if revision not in self.branches.get(repo, set()):
            return 404, {"X-Error-Code": "RevisionNotFound"}, {"error": f"no branch {revision}"}
        store = self.files.setdefault(f"{repo}@{revision}", {})
        for line in body.splitlines():
            item = json.loads(line)
            if item["key"] == "file":
                store[item["value"]["path"]] = base64.b64decode(item["value"]["content"])
        oid = f"{len(self.requests):040x}"
        return 200, {}, {"commitUrl": f"{self.endpoint}/datasets/{repo}/commit/{oid}", "commitOid": oid}


def _handler(hub: FakeHub) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def _serve(self) -> None:
            body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
            hub.requests.append((self.command, self.path, dict(self.headers), body))
            status, headers, payload = hub.handle(self.command, self.path, body)
            data = json.dumps(payload).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            for key, value in headers.items():
                self.send_header(key, value)
            self.end_headers()
            self.wfile.write(data)

        def do_GET(self) -> None:
            self._serve()

        def do_POST(self) -> None:
            self._serve()

        def do_DELETE(self) -> None:
            self._serve()

        def log_message(self, format: str, *args: Any) -> None:
            pass

    return Handler


@contextmanager
def fake_hub() -> Iterator[FakeHub]:
    hub = FakeHub()
    server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(hub))
    hub.endpoint = f"http://127.0.0.1:{server.server_address[1]}"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield hub
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
