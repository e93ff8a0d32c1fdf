#!/usr/bin/env bash
# Install everything (idempotent) and run the main job: train + evaluate the conveyor Q-learning agent, film one
# ClutterGraspSlide-v1 episode of the bundled G&S agent (about 10 minutes on 2 cores). Extra arguments go to it.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
set -o pipefail
.venv/bin/maniskill-pnp quickstart "$@" 2>&1 | grep -v -E '^(nanobind: | - leaked|See https://nanobind)'
