#!/usr/bin/env bash
# One-command setup of YOWO on a fresh Debian 12 + Python 3.11 machine:
# apt packages, a venv with ROS 2 Jazzy + the compute stack from PyPI, the
# interface packages built with rosidl, and editable installs of our packages.
# Idempotent: each step is skipped when its inputs have not changed.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${YOWO_VENV:-$ROOT/.venv}
PYTHON=${PYTHON:-python3.11}
STAMPS=$VENV/.yowo-stamps
log() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }

# --- 1. system packages -----------------------------------------------------
# chromium: the report test renders report.html headless (a screenshot).
APT_PKGS=(libusb-1.0-0 cmake build-essential python3-dev iproute2 chromium)
missing=()
for p in "${APT_PKGS[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if ((${#missing[@]})); then
  log "apt: installing ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
command -v "$PYTHON" >/dev/null || PYTHON=python3
"$PYTHON" -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' \
  || { echo "setup: Python 3.11 is required (the ros-jazzy wheels are cp311)" >&2; exit 1; }

# --- 2. venv + pinned requirements ------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  log "venv: creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
mkdir -p "$STAMPS"
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
hash_of() { cat "$@" | sha256sum | cut -d' ' -f1; }
pip_q() {  # quiet pip; its whole output only when it fails
  "$VENV/bin/python" -m pip "$@" >"$STAMPS/pip.log" 2>&1 \
    || { echo "setup: pip $* failed:" >&2; tail -40 "$STAMPS/pip.log" >&2; exit 1; }
}

req_hash=$(hash_of "$ROOT/requirements.txt" "$ROOT/constraints.txt" "$ROOT/requirements-nodeps.txt")
if ! stamp_ok requirements "$req_hash"; then
  log "pip: installing requirements (pinned)"
  pip_q install --upgrade pip wheel
  pip_q install -r "$ROOT/requirements.txt" -c "$ROOT/constraints.txt"
  pip_q install --no-deps -r "$ROOT/requirements-nodeps.txt"
  echo "$req_hash" > "$STAMPS/requirements"
fi

# --- 3. interface packages (ament_cmake + rosidl) ----------------------------
build_interfaces() {  # <source dir> <package name>
  local src=$1 name=$2 h
  h=$(find "$src" -type f | sort | xargs cat | sha256sum | cut -d' ' -f1)
  if stamp_ok "$name" "$h" && "$VENV/bin/python" -c "import $name.msg" 2>/dev/null; then return; fi
  log "build: $name"
  local build=$ROOT/build/$name
  (
    export PATH=$VENV/bin:$PATH AMENT_PREFIX_PATH=$VENV CMAKE_PREFIX_PATH=$VENV
    cmake -S "$src" -B "$build" -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
      -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_PROJECT_INCLUDE="$ROOT/cmake/fix_wheel_py_includes.cmake" \
      >"$build.log" 2>&1 &&
    cmake --build "$build" -j2 >>"$build.log" 2>&1 &&
    cmake --install "$build" >>"$build.log" 2>&1
  ) || { echo "setup: building $name failed; log: $build.log" >&2; tail -30 "$build.log" >&2; exit 1; }
  echo "$h" > "$STAMPS/$name"
}
mkdir -p "$ROOT/build"
# tf2_msgs has no wheel: build our identical TFMessage unless the environment has it.
if [ -f "$STAMPS/tf2_msgs" ] || ! "$VENV/bin/python" -c 'import tf2_msgs.msg' 2>/dev/null; then
  build_interfaces "$ROOT/src/tf2_msgs_compat" tf2_msgs
fi
build_interfaces "$ROOT/src/yowo_msgs" yowo_msgs

# --- 4. our Python packages (editable) ---------------------------------------
PY_PKGS=(yowo_common yowo_ego yowo_cmc yowo_fusion yowo_sim yowo_bringup yowo_eval)
setup_files=(); for p in "${PY_PKGS[@]}"; do setup_files+=("$ROOT/src/$p/setup.py"); done
py_hash=$(hash_of "${setup_files[@]}")
if ! stamp_ok python-packages "$py_hash"; then
  log "pip: editable install of ${PY_PKGS[*]}"
  args=(); for p in "${PY_PKGS[@]}"; do args+=(-e "$ROOT/src/$p"); done
  pip_q install --no-deps --no-build-isolation "${args[@]}"
  echo "$py_hash" > "$STAMPS/python-packages"
fi
"$VENV/bin/python" -c 'import yowo_common, yowo_msgs.msg, tf2_msgs.msg' \
  || { echo "setup: the YOWO packages are not importable" >&2; exit 1; }
log "ready: activate with 'source $VENV/bin/activate' (or run $VENV/bin/yowo)"
