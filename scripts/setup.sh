#!/usr/bin/env bash
# Installs everything maniskill_pnp needs on a fresh Debian bookworm machine (root), idempotently:
#   1. Vulkan loader + Mesa lavapipe from bookworm-backports (CPU rendering; skipped parts already present),
#   2. a Python 3.11 virtual environment in .venv with the package and its pinned dependencies.
# A second run only checks and returns within seconds.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
venv="${MANISKILL_PNP_VENV:-$root/.venv}"
# One environment serves both the main job and the tests, so either command finds it ready after the other.
extras="test"

log() { printf '[setup] %s\n' "$*" >&2; }

# ---------------------------------------------------------------- system packages (CPU rendering)
need_mesa() {
    # lavapipe from bookworm (Mesa 22) lacks VK_KHR_external_semaphore_fd, which SAPIEN needs: require Mesa >= 25.
    local v
    v="$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)"
    [[ -z "$v" ]] && return 0
    dpkg --compare-versions "$v" lt 25 && return 0
    dpkg-query -W -f='${Status}' libvulkan1 2>/dev/null | grep -q "install ok installed" || return 0
    return 1
}

if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then
    log "NVIDIA GPU found: leaving the system's Vulkan/GL drivers untouched (SAPIEN renders on the GPU)"
elif need_mesa; then
    if [[ "$(id -u)" != 0 ]]; then
        log "error: Mesa >= 25 (lavapipe) is needed for CPU rendering; run this script as root once"; exit 1
    fi
    src=/etc/apt/sources.list.d/bookworm-backports.sources
    if [[ ! -f "$src" ]]; then
        # Reuse the Debian mirror this machine is already configured with.
        uri="$(awk '/^URIs:/ {print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)"
        [[ -n "$uri" ]] || uri="$(awk '/^deb / && $3 ~ /^bookworm$/ {print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)"
        [[ -n "$uri" ]] || { log "error: no Debian mirror found in /etc/apt to add bookworm-backports"; exit 1; }
        printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
            "$uri" > "$src"
        log "added bookworm-backports ($src)"
    fi
    log "installing Mesa lavapipe and the Vulkan loader from bookworm-backports"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
else
    log "Mesa lavapipe $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers) already installed"
fi
# ffmpeg for video writing comes with imageio-ffmpeg's wheel; nothing else is needed from apt.

# ---------------------------------------------------------------- python environment
py="${PYTHON:-}"
if [[ -z "$py" ]]; then
    for c in python3.11 "$HOME/.pyenv/versions/3.11.7/bin/python" python3; do
        if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then py="$c"; break; fi
    done
fi
[[ -n "$py" ]] || { log "error: Python 3.11 not found (set PYTHON=/path/to/python3.11)"; exit 1; }

[[ -x "$venv/bin/python" ]] || { log "creating $venv"; "$py" -m venv "$venv"; }
stamp="$venv/.maniskill_pnp-installed"
want="$(cat pyproject.toml | sha256sum | cut -d' ' -f1) extras=$extras"
if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
    log "python environment up to date ($venv)"
else
    spec="."
    [[ -n "$extras" ]] && spec=".[$extras]"
    log "installing maniskill_pnp${extras:+[$extras]} into $venv (first time: a few minutes)"
    pip_log="$venv/pip-install.log"
    if ! { "$venv/bin/python" -m pip install -q --upgrade pip && "$venv/bin/python" -m pip install -q -e "$spec"; } >"$pip_log" 2>&1; then
        tail -n 30 "$pip_log" >&2
        log "error: pip install failed (full log: $pip_log)"; exit 1
    fi
    echo "$want" > "$stamp"
fi
