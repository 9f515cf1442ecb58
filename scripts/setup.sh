#!/usr/bin/env bash
# Provisioning for the tests (sourced or run by scripts/test.sh): the firmware target, the emulator
# the end-to-end tests boot, and numpy/scipy for the SciPy peer check. Safe to run again.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup-embedded.sh
if ! python3 -c "import numpy, scipy" 2>/dev/null; then
    echo "installing numpy and scipy for the SciPy peer check"
    python3 -m pip install --quiet --disable-pip-version-check numpy scipy
fi
