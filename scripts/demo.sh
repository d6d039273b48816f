#!/usr/bin/env bash
# README command 1: set up (idempotent) and run the main job on an embedded default:
# a generated camera rig, calibrated through the ROS 2 node (or offline with --offline).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/scripts/setup_env.sh"
exec "$repo/.venv/bin/densecalib" demo "$@"
