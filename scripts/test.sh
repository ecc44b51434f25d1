#!/usr/bin/env bash
# Sets up the machine if needed and runs the whole test suite (unit and integration tests).
# Tests that need the ICT-FaceKit data look for ../shared/data/ict-facekit and print why
# they skip when it is absent.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
# The cross-check tools installed by setup.sh (python3 with pxr and c3d, the rerun command).
python_env="${HELMCAP_PYTHON_ENV:-$HOME/.cache/helmcap-python}"
if [ -d "$python_env/bin" ]; then export PATH="$python_env/bin:$PATH"; fi
cargo test --locked "$@"
