#!/usr/bin/env bash
# Sets up the machine if needed, builds helmcap in release mode and runs the demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
cargo run --release --locked -- demo "$@"
