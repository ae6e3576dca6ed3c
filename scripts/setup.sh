#!/usr/bin/env bash
# Idempotent set-up on a fresh machine: Python 3.12 (via .python-version), uv, and the locked environment.
set -euo pipefail
cd "$(dirname "$0")/.."
export UV_PYTHON_DOWNLOADS=never
if ! python3 -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' 2>/dev/null; then
  echo "bagport needs Python 3.12 as python3 here (pyenv reads .python-version); found: $(python3 --version 2>&1)" >&2
  exit 1
fi
if ! python3 -m uv --version >/dev/null 2>&1; then
  echo "installing uv ..." >&2
  python3 -m pip install --quiet --disable-pip-version-check 'uv==0.13.9'
fi
# --locked: install exactly uv.lock; the lerobot extra is the real consumer used by `bagport validate` and the tests.
python3 -m uv sync --locked --all-extras --quiet --compile-bytecode
