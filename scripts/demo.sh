#!/usr/bin/env bash
# The main job on bundled sample data: synthesise a small fleet, convert it through the Prefect flow
# (no Prefect server, local staging), print the summary, and validate the result with LeRobot.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
bp() { .venv/bin/bagport "$@"; }
rm -rf out/sample-bags
bp synth --out out/sample-bags --episodes 4 --duration 5
bp convert --manifest out/sample-bags/manifest.yaml --contract configs/contracts/sample_robot.yaml \
  --output out/sample-dataset --overwrite
bp validate out/sample-dataset
