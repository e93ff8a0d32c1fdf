#!/usr/bin/env bash
# Install everything (idempotent) and run the main job: plan and execute a pick-and-place, save video + strip.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
set -o pipefail
.venv/bin/maniskill-pnp demo "$@" 2>&1 | grep -v -E '^(nanobind: | - leaked|See https://nanobind)'
