#!/usr/bin/env bash
# The main job (README): installs what the emulated controller needs, then runs the whole loop —
# emulated controller with an emulated arm, record, calibrate, upload, stream the pose.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup target add thumbv7em-none-eabihf >/dev/null
if ! command -v qemu-system-arm >/dev/null; then
    echo "installing qemu-system-arm"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq qemu-system-arm >/dev/null
fi
cargo run --release -p kincal -- demo "$@"
