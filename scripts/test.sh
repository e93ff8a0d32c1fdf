#!/usr/bin/env bash
# Install everything (idempotent) and run the test suite on the CPU. Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
# One test process per core, at most 4 (each holds ManiSkill envs of ~2 GB); every test of a file runs in one process,
# so a file's shared env fixtures are built once. MANISKILL_PNP_TEST_WORKERS=0 runs them all in this process.
cores="$(nproc)"
workers="${MANISKILL_PNP_TEST_WORKERS:-$(( cores < 4 ? cores : 4 ))}"
parallel=()
[[ "$workers" -gt 0 ]] && parallel=(-n "$workers" --dist loadfile)
# OMPL's nanobind bindings print reference-leak notes at interpreter exit; drop them so pytest's summary stays last.
# The 15 slowest tests are listed at the end, so that the suite's cost stays visible.
set -o pipefail
.venv/bin/python -m pytest -q "${parallel[@]}" --durations=15 "$@" 2>&1 | grep -v -E '^(nanobind: | - leaked|See https://nanobind)'
