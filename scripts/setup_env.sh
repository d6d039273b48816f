#!/usr/bin/env bash
# Idempotent set-up of the project's virtual environment (.venv in the repo root):
#   - creates .venv with python3.11 if missing,
#   - installs the pinned dependencies when requirements*.txt or setup.py changed (stamp file;
#     requirements-nodeps.txt with --no-deps),
#   - installs this package in editable mode (console scripts densecalib, densecalib_node),
#   - generates the ROS interface packages into .venv when they cannot be imported or their sources
#     changed (scripts/build_interfaces.sh: tf2_msgs, which PyPI lacks, and densecalib_interfaces,
#     the node's Calibrate action).
# A second run only checks the stamp and an import: it takes a few seconds.
# Only package registries are contacted; nothing is downloaded at run time afterwards.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv"
py="${DENSECALIB_PYTHON:-python3.11}"
command -v "$py" >/dev/null 2>&1 || py=python3

log() { echo "[setup] $*" >&2; }

if [ ! -x "$venv/bin/python" ]; then
  log "creating virtual environment $venv with $($py --version 2>&1)"
  "$py" -m venv "$venv"
fi
vpy="$venv/bin/python"

stamp="$venv/.densecalib_stamp"
want="$(cat "$repo/requirements.txt" "$repo/requirements-ros.txt" "$repo/requirements-nodeps.txt" \
        "$repo/setup.py" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  log "installing pinned dependencies (first run: about a minute)"
  "$vpy" -m pip install --quiet --disable-pip-version-check --upgrade pip
  "$vpy" -m pip install --quiet --disable-pip-version-check \
      -r "$repo/requirements.txt" -r "$repo/requirements-ros.txt"
  # Without their declared dependencies (see the file); their real needs are in requirements.txt.
  "$vpy" -m pip install --quiet --disable-pip-version-check --no-deps -r "$repo/requirements-nodeps.txt"
  "$vpy" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e "$repo"
  echo "$want" > "$stamp"
else
  log "dependencies up to date"
fi

bash "$repo/scripts/build_interfaces.sh" "$venv"
log "environment ready: $venv"
