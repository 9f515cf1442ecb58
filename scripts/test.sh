#!/usr/bin/env bash
# The test command (README, .ci/run): installs what the tests need, then runs them all.
set -euo pipefail
cd "$(dirname "$0")/.."

# Firmware target and the emulator the end-to-end tests boot.
rustup target add thumbv7em-none-eabihf >/dev/null
if ! command -v qemu-system-arm >/dev/null; then
    echo "installing qemu-system-arm"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq qemu-system-arm >/dev/null
fi
# The SciPy peer check (tests/tests/scipy_peer.rs) needs numpy and scipy.
if ! python3 -c "import numpy, scipy" 2>/dev/null; then
    echo "installing numpy and scipy for the SciPy peer check"
    python3 -m pip install --quiet --disable-pip-version-check numpy scipy
fi

# Both firmware images must build: the emulated controller and the real board.
cargo build-emulated
cargo build-stm32
# Firmware logic on the host (its own workspace), then everything else.
cargo test --manifest-path firmware/Cargo.toml --release
cargo test --workspace --release
