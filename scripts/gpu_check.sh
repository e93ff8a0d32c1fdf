#!/usr/bin/env bash
# The package's GPU paths in one go, for a short lease of one NVIDIA GPU (at most 8 minutes in all):
#   setup (idempotent), nvidia-smi, the gpu-marked tests, bench batched-decisions (GPU simulation),
#   bench pixel-memory on CUDA, and last (cut short first) two minutes of gs-thesis training throughput.
# Each step runs under its own `timeout`, and no step starts past the overall budget; every step's output, the
# pytest junit XML, the benchmarks' JSON and a summary.md (step, exit code, wall time) go into one folder.
#
# usage: bash scripts/gpu_check.sh [--out DIR] [--dry-run]
#   --out DIR   output folder (default: runs/gpu_check/<date>-<time>)
#   --dry-run   print each step's command line, one per line, and run nothing (needs no GPU)
# MANISKILL_PNP_GPU_CHECK_BUDGET_S sets the overall budget (default 480 s).
# Exit codes: 0 every step passed, 1 a step failed, timed out (124: its timeout) or was not run, 2 no usable NVIDIA
# GPU (nothing was run), 64 bad arguments.
set -euo pipefail
here="$(pwd)"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

usage() { sed -n '2,13p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
out="" dry=0
while [[ $# -gt 0 ]]; do
    case "$1" in
        --out) [[ $# -ge 2 ]] || { echo "gpu_check.sh: --out needs a folder" >&2; exit 64; }; out="$2"; shift 2 ;;
        --out=*) out="${1#--out=}"; shift ;;
        --dry-run) dry=1; shift ;;
        -h|--help) usage; exit 0 ;;
        *) echo "gpu_check.sh: unknown argument '$1'" >&2; usage >&2; exit 64 ;;
    esac
done
if [[ -z "$out" ]]; then
    out="runs/gpu_check/$(date +%Y%m%d-%H%M%S)"
elif [[ "$out" != /* ]]; then
    out="$here/$out"  # relative to where the script was called from
fi

venv="${MANISKILL_PNP_VENV:-.venv}"
py="$venv/bin/python"
mp="$venv/bin/maniskill-pnp"
budget_s="${MANISKILL_PNP_GPU_CHECK_BUDGET_S:-480}"  # the whole check, setup included
grace_s=5     # `timeout -k`: a step that ignores SIGTERM is killed this long after it

# Steps in the order they run: name, timeout (s), command. The CPU-bound training throughput goes last, so that a
# slow step before it shortens only that one.
steps=(setup nvidia-smi pytest-gpu batched-decisions pixel-memory training-throughput)
declare -A limit=([setup]=30 [nvidia-smi]=10 [pytest-gpu]=90 [batched-decisions]=110 [pixel-memory]=60
                  [training-throughput]=170)
step_cmd() {  # sets cmd to the command of step $1
    case "$1" in
        setup) cmd=(bash scripts/setup.sh) ;;
        nvidia-smi) cmd=(nvidia-smi) ;;
        pytest-gpu) cmd=("$py" -m pytest -m gpu -q tests/ --timeout=60 "--junitxml=$out/pytest_gpu.xml") ;;
        batched-decisions) cmd=("$mp" bench batched-decisions --num-envs 1 4 16 64 --out "$out/bench") ;;
        pixel-memory) cmd=("$mp" bench pixel-memory --device cuda --repeats 3 --out "$out/bench") ;;
        # Learner and acting on the GPU (the in-process collector: a worker process would act on the CPU, seconds a
        # DenseNet-121 decision); the turn's JSON names the device.
        training-throughput) cmd=("$mp" bench training-throughput --variants gs-thesis,device=cuda,collector=direct
                                  --minutes 2 --repeats 1
                                  --out "$out/bench") ;;
        *) echo "gpu_check.sh: no step $1" >&2; exit 70 ;;
    esac
}

if [[ "$dry" == 1 ]]; then
    for s in "${steps[@]}"; do
        step_cmd "$s"
        line="$(printf '%q ' timeout -k "$grace_s" "${limit[$s]}" "${cmd[@]}")"
        echo "${line% }"
    done
    exit 0
fi

# ---------------------------------------------------------------- a GPU, or nothing at all
now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }
t_start="$(now)"  # the budget counts from here
no_gpu() { echo "gpu_check.sh needs an NVIDIA GPU ($1); nothing was run" >&2; exit 2; }
command -v nvidia-smi >/dev/null 2>&1 || no_gpu "no nvidia-smi on PATH"
gpus="$(timeout 20 nvidia-smi -L 2>/dev/null || true)"
grep -q '^GPU ' <<<"$gpus" || no_gpu "nvidia-smi found none"
torch_cuda() { timeout 30 "$py" -c 'import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)' >/dev/null 2>&1; }
torch_checked=0
if [[ -x "$py" ]]; then
    torch_cuda || no_gpu "nvidia-smi lists one, but torch.cuda.is_available() is False"
    torch_checked=1
fi

mkdir -p "$out/bench"
export PYTHONUNBUFFERED=1
export MANISKILL_PNP_PROGRESS_INTERVAL="${MANISKILL_PNP_PROGRESS_INTERVAL:-10}"  # a progress line every 10 s
commit="$(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
[[ -n "$(git status --porcelain --untracked-files=no 2>/dev/null)" ]] && commit+=" (with uncommitted changes)"
rows=()
write_summary() {
    {
        echo "# GPU check $(date -d "@${t_start%.*}" '+%Y-%m-%d %H:%M:%S %Z')"
        echo
        echo "- commit: $commit; host: $(hostname)"
        sed 's/^/- /' <<<"$gpus"
        echo "- folder: $out (one log per step; bench/*.json; pytest_gpu.xml)"
        echo "- exit code 124 (137: killed ${grace_s} s later): the step's timeout ran out; \"not run\": the overall budget"\
             "of ${budget_s} s was spent, or setup failed"
        echo
        echo "| step | exit code | wall s | timeout s | log | command |"
        echo "|---|---|---|---|---|---|"
        printf '%s\n' "${rows[@]}"
        echo
        echo "total wall time: $(elapsed "$t_start") s"
    } >"$out/summary.md"
}

failed=0 stop="" stop_rc=1
for i in "${!steps[@]}"; do
    s="${steps[$i]}"
    step_cmd "$s"
    log="$(printf '%02d' $((i + 1)))-$s.log"
    shown="$(printf '%q ' "${cmd[@]}")"; shown="${shown% }"
    left=$(awk -v t="$(elapsed "$t_start")" -v b="$budget_s" -v g="$grace_s" 'BEGIN { printf "%d", b - t - g }')
    t=$(( ${limit[$s]} < left ? ${limit[$s]} : left ))
    if [[ -n "$stop" || "$t" -lt 5 ]]; then
        rows+=("| $s | not run | | ${limit[$s]} | | \`$shown\` |")
        failed=1
        echo "[gpu_check] $s: not run (${stop:-budget spent})" >&2
        write_summary
        continue
    fi
    echo "[gpu_check] $s (timeout ${t} s): $shown" >&2
    t0="$(now)"
    set +e
    timeout -k "$grace_s" "$t" "${cmd[@]}" 2>&1 | tee "$out/$log"
    rc="${PIPESTATUS[0]}"
    set -e
    wall="$(elapsed "$t0")"
    [[ "$rc" == 0 ]] || failed=1
    rows+=("| $s | $rc | $wall | $t | $log | \`$shown\` |")
    echo "[gpu_check] $s: exit code $rc after $wall s" >&2
    if [[ "$s" == setup ]]; then
        if [[ ! -x "$mp" ]]; then
            stop="setup did not install $mp"
        elif [[ "$torch_checked" == 0 ]] && ! torch_cuda; then
            stop="torch.cuda.is_available() is False after setup" stop_rc=2
        fi
    fi
    write_summary
done
if [[ -f "$out/pytest_gpu.xml" ]]; then
    tests="$(grep -o '<testsuite [^>]*>' "$out/pytest_gpu.xml" | head -n 1 | grep -oE '(tests|failures|errors|skipped)="[0-9]+"' | tr '\n' ' ' || true)"
    printf '\npytest -m gpu: %s\n' "$tests" >>"$out/summary.md"
fi
echo "[gpu_check] summary: $out/summary.md" >&2
cat "$out/summary.md"
[[ -z "$stop" ]] || { echo "[gpu_check] stopped: $stop" >&2; exit "$stop_rc"; }
exit "$failed"
