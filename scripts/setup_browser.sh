#!/usr/bin/env bash
# Headless Chromium (Debian's package) for the test that renders the HTML QA report. Installs only when missing.
set -euo pipefail
if command -v chromium >/dev/null 2>&1; then
  exit 0
fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "installing chromium (Debian) for the QA report rendering test ..." >&2
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null
else
  echo "chromium is missing and cannot be installed here (needs root and apt-get): the QA report rendering test will fail" >&2
fi
