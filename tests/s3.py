"""A real S3-compatible HTTP endpoint on loopback (moto's server mode), for s3fs through the AWS env."""

from __future__ import annotations

import os
import socket
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager

from moto.server import ThreadedMotoServer
from s3fs import S3FileSystem

__all__ = ["KEY_ID", "SECRET", "moto_s3", "s3_bucket"]

KEY_ID = "AKIABAGPORTTESTKEY01"
SECRET = "bagport-test-secret-key"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextmanager
def moto_s3() -> Iterator[dict[str, str]]:
    """Start the server and point the standard AWS variables at it; restore them afterwards."""
    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    # moto's backends live in the process, shared by every server it starts: begin with an empty store.
    urllib.request.urlopen(urllib.request.Request(f"http://127.0.0.1:{port}/moto-api/reset", method="POST"))
    env = {
        "AWS_ACCESS_KEY_ID": KEY_ID,
        "AWS_SECRET_ACCESS_KEY": SECRET,
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
    }
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    # fsspec caches filesystems by their arguments; one made for an earlier server (the endpoint comes
    # from the environment, not the arguments) would still point at that server's dead port.
    S3FileSystem.clear_instance_cache()
    try:
        yield env
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        server.stop()
        S3FileSystem.clear_instance_cache()


def s3_bucket(env: dict[str, str], bucket: str) -> S3FileSystem:
    """An s3fs client of :func:`moto_s3`'s endpoint (``env``), with ``bucket`` made if it is missing (a module's
    tests share one server)."""
    fs = S3FileSystem(endpoint_url=env["AWS_ENDPOINT_URL"])
    if not fs.exists(bucket):
        fs.mkdir(bucket)
    return fs
