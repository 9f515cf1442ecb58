#!/usr/bin/env bash
# The test command (README, .ci/run): installs what the tests need, then runs them all.
set -euo pipefail
cd "$(dirname "$0")/.."

# Firmware target and the emulator the end-to-end tests boot.
source scripts/setup-embedded.sh
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
