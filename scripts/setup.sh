#!/usr/bin/env bash
# Provisioning for the tests (sourced or run by scripts/test.sh): the firmware target, the emulator
# the end-to-end tests boot, numpy/scipy for the SciPy peer check, and mdBook for the book. Safe to
# run again.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup-embedded.sh
if ! python3 -c "import numpy, scipy" 2>/dev/null; then
    echo "installing numpy and scipy for the SciPy peer check"
    python3 -m pip install --quiet --disable-pip-version-check numpy scipy
fi
MDBOOK_VERSION=0.5.4
if [ "$(mdbook --version 2>/dev/null)" != "mdbook v$MDBOOK_VERSION" ]; then
    echo "installing mdbook $MDBOOK_VERSION for the book (a few minutes, once)"
    cargo install --quiet --locked mdbook --version "$MDBOOK_VERSION" --no-default-features --features search
fi
