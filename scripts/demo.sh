#!/usr/bin/env bash
# The main job (README): installs what the emulated controller needs, then runs the whole loop —
# emulated controller with an emulated arm, record, calibrate, upload, stream the pose.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup-embedded.sh
cargo build-emulated
cargo run --release -p kincal -- demo "$@"
