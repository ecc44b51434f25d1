#!/usr/bin/env bash
# Installs what helmcap needs to build and test on Debian (run as root, or with sudo):
# system libraries for the camera, calibration and serial crates, and a Rust toolchain
# (1.85 or newer) when none is found. Safe to run again: it installs only what is missing.
set -euo pipefail

packages=(build-essential pkg-config curl ca-certificates clang libclang-dev libopencv-dev
          libv4l-dev libudev-dev)
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
