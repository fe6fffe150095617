#!/usr/bin/env bash
# One-time set-up on a fresh machine (idempotent): Debian packages for headless rendering and video
# decoding, a Python 3.12 virtual environment in .venv with the pinned stack, and this package installed
# in editable mode. Source it (`source scripts/setup.sh`) or let scripts/demo.sh / scripts/test.sh call it.
# Sourced, it changes only the environment variables below: the strict shell options and the `cd` stay inside
# a subshell, so a later failing command does not close the caller's shell.
mosaic_repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

(
    set -euo pipefail
    cd "$mosaic_repo_root"

    apt_packages=(libosmesa6 libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libglx-mesa0 ffmpeg)
    missing=()
    for package in "${apt_packages[@]}"; do
        dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
    done
    if ((${#missing[@]})); then
        echo "[setup] installing Debian packages: ${missing[*]}"
        sudo_cmd=""
        [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
        $sudo_cmd apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${missing[@]}" >/dev/null
    fi

    if [ ! -x .venv/bin/python ]; then
        if command -v pyenv >/dev/null 2>&1 && pyenv prefix 3.12.1 >/dev/null 2>&1; then
            python312="$(pyenv prefix 3.12.1)/bin/python"
        elif command -v python3.12 >/dev/null 2>&1; then
            python312="$(command -v python3.12)"
        else
            echo "[setup] error: Python 3.12 not found: install it with 'pyenv install 3.12.1'" >&2
            exit 1
        fi
        echo "[setup] creating .venv with $python312"
        "$python312" -m venv .venv
    fi

    stamp=.venv/.mosaic-installed
    if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ scripts/setup.sh -nt "$stamp" ] \
        || [ plugins/lerobot_policy_mosaic/pyproject.toml -nt "$stamp" ] || [ plugins/lerobot_env_mosaic/pyproject.toml -nt "$stamp" ]; then
        echo "[setup] installing Python packages (first time: about a minute, 7 GB)"
        # uv downloads and unpacks the pinned wheels in parallel: on a fresh 2-core machine about 1 minute, where
        # pip takes 3. The plugin distributions are what LeRobot's discovery imports for --policy.type=mosaic and
        # --env.type=mosaic.
        .venv/bin/python -m pip install -q "uv==0.9.30"
        .venv/bin/python -m uv pip install -q --compile-bytecode --python .venv/bin/python \
            -e ".[test]" -e plugins/lerobot_policy_mosaic -e plugins/lerobot_env_mosaic
        touch "$stamp"
    fi
) || { mosaic_setup_status=$?; echo "[setup] failed (exit $mosaic_setup_status)" >&2; return "$mosaic_setup_status" 2>/dev/null || exit "$mosaic_setup_status"; }

export MUJOCO_GL="${MUJOCO_GL:-egl}"
export HF_HUB_OFFLINE="${HF_HUB_OFFLINE:-1}"
export WANDB_MODE="${WANDB_MODE:-disabled}"
export PATH="$mosaic_repo_root/.venv/bin:$PATH"
