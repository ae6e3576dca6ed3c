#!/usr/bin/env bash
# The whole test suite: lint (ruff), types (mypy strict), import layers (import-linter), the docs site
# (mkdocs --strict: a broken link fails), then pytest (slow end-to-end tests included).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
bash scripts/setup_browser.sh
bash scripts/setup_stack.sh  # PostgreSQL for the native stack test (tests/stack)
.venv/bin/ruff check src tasks flows tests bench
.venv/bin/ruff format --check src tasks flows tests bench
.venv/bin/mypy src/bagport tasks flows tests bench
.venv/bin/lint-imports --no-cache
NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict  # not --quiet: it hides the warnings --strict fails on
# Two workers (pytest-xdist), a module's tests on one of them (tests/conftest.py groups them, slow modules
# first): a single pytest left a core idle 40% of the time (server boots, subprocesses, one-threaded tests).
.venv/bin/pytest -n 2 --dist loadgroup --no-loadscope-reorder "$@"
