#!/usr/bin/env bash
# Install everything (idempotent) and run the test suite on the CPU. Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
# OMPL's nanobind bindings print reference-leak notes at interpreter exit; drop them so pytest's summary stays last.
set -o pipefail
.venv/bin/python -m pytest -q "$@" 2>&1 | grep -v -E '^(nanobind: | - leaked|See https://nanobind)'
