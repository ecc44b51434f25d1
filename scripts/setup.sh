#!/usr/bin/env bash
# Installs what helmcap needs to build and test on Debian (run as root, or with sudo):
# system libraries for the camera, calibration and serial crates, and a Rust toolchain
# (1.85 or newer) when none is found. Safe to run again: it installs only what is missing.
set -euo pipefail

# opencv-doc: OpenCV's stereo sample images (left01..14.jpg, right01..14.jpg) that the
# calibration tests use; ffmpeg: ffprobe reads video timecode tracks (tests write one).
# chromium: the report tests load the dailies pages in a headless browser (they skip without it).
packages=(build-essential pkg-config curl ca-certificates clang libclang-dev libopencv-dev
          libv4l-dev libudev-dev opencv-doc ffmpeg chromium)
missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: installing the Rust toolchain (rustup)"
  curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y --profile minimal \
    --component rustfmt,clippy
  . "$HOME/.cargo/env"
fi
rust_minor=$(rustc --version | sed -E 's/rustc 1\.([0-9]+).*/\1/')
if [ "$rust_minor" -lt 85 ]; then
  if command -v rustup >/dev/null 2>&1; then
    rustup update stable
  else
    echo "setup: rustc $(rustc --version) is older than 1.85; install a newer toolchain with rustup" >&2
    exit 1
  fi
fi

# Python tools the tests use to cross-check our files with other readers: Pixar's USD
# (usd-core), a C3D reader (c3d) and the rerun command (rerun-sdk, matching the rerun crate).
# They go into a virtual environment of their own; without network the checks skip.
python_env="${HELMCAP_PYTHON_ENV:-$HOME/.cache/helmcap-python}"
if [ ! -x "$python_env/bin/rerun" ] || ! "$python_env/bin/python" -c "import pxr, c3d" 2>/dev/null; then
  echo "setup: installing the Python cross-check tools into $python_env"
  if ! python3 -m venv "$python_env" 2>/dev/null; then
    # Debian ships venv (and its pip) separately.
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
      python3 python3-venv python3-pip || true
    python3 -m venv "$python_env" || true
  fi
  if ! "$python_env/bin/pip" install -q usd-core c3d rerun-sdk==0.36.3; then
    echo "setup: could not install usd-core, c3d and rerun-sdk; the tests that use them skip" >&2
  fi
fi
# trimesh reads the PLY exports back (UVs per vertex, triangles) in the mesh tests.
if [ -x "$python_env/bin/python" ] && ! "$python_env/bin/python" -c "import trimesh" 2>/dev/null; then
  echo "setup: installing trimesh into $python_env"
  "$python_env/bin/pip" install -q trimesh ||
    echo "setup: could not install trimesh; the PLY cross-check skips" >&2
fi

# The Live Link Face UDP decoder the streaming test checks our packets with.
if [ -x "$python_env/bin/python" ] && ! "$python_env/bin/python" -c "import pylivelinkface" 2>/dev/null; then
  echo "setup: installing pylivelinkface into $python_env"
  if ! "$python_env/bin/pip" install -q pylivelinkface; then
    echo "setup: could not install pylivelinkface; the Live Link UDP test skips" >&2
  fi
fi

# The Open Job Description CLI (`openjd check`, `openjd run`), which checks and runs the farm
# job bundles `helmcap farm job` writes, exactly as a farm worker would.
if [ -x "$python_env/bin/python" ] && [ ! -x "$python_env/bin/openjd" ]; then
  echo "setup: installing openjd-cli into $python_env"
  if ! "$python_env/bin/pip" install -q openjd-cli; then
    echo "setup: could not install openjd-cli; the farm job tests skip" >&2
  fi
fi

# Blender as a Python module (bpy), which imports face_skel.usda in the animation tests.
# It pins numpy below 2 (rerun-sdk needs 2), so it has an environment of its own.
blender_env="${HELMCAP_BLENDER_ENV:-$HOME/.cache/helmcap-blender}"
if [ ! -x "$blender_env/bin/python" ] || ! "$blender_env/bin/python" -c "import bpy" 2>/dev/null; then
  echo "setup: installing Blender's bpy into $blender_env"
  if ! { python3 -m venv "$blender_env" && "$blender_env/bin/pip" install -q bpy; }; then
    echo "setup: could not install bpy; the Blender import test skips" >&2
  fi
fi
