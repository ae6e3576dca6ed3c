#!/usr/bin/env bash
# PostgreSQL (Debian's package) for scripts/stack.sh and its test. Installs only when missing.
#   --print-initdb: print the path of initdb (installing PostgreSQL first if needed)
set -euo pipefail
find_initdb() {
  local found
  found="$(ls -1 /usr/lib/postgresql/*/bin/initdb 2>/dev/null | sort -V | tail -n 1)"
  [ -n "$found" ] || found="$(command -v initdb 2>/dev/null || true)"
  [ -z "$found" ] || readlink -f "$found"
}
if [ -z "$(find_initdb)" ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing postgresql (Debian) for the native stack (scripts/stack.sh) ..." >&2
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends postgresql >/dev/null
  else
    echo "PostgreSQL is missing and cannot be installed here (needs root and apt-get): scripts/stack.sh and its test will fail" >&2
    exit 1
  fi
fi
if [ "${1:-}" = --print-initdb ]; then
  find_initdb
fi
