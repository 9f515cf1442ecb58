#!/usr/bin/env bash
# Provisioning for the tests (sourced or run by scripts/test.sh): the firmware target, the emulator
# the end-to-end tests boot, numpy/scipy for the SciPy peer check and pinocchio for the public-arm
# peer (bench/pinocchio_peer.py). Safe to run again.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup-embedded.sh
if ! python3 -c "import numpy, scipy" 2>/dev/null; then
    echo "installing numpy and scipy for the SciPy peer check"
    python3 -m pip install --quiet --disable-pip-version-check numpy scipy
fi
if ! python3 -c "import pinocchio" 2>/dev/null; then
    echo "installing pinocchio (pip package pin) for the public-arm peer"
    python3 -m pip install --quiet --disable-pip-version-check pin
fi
