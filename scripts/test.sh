#!/usr/bin/env bash
# The test command (README, .ci/run): installs what the tests need, then runs them all.
set -euo pipefail
cd "$(dirname "$0")/.."

# The SciPy peer check (tests/tests/scipy_peer.rs) needs numpy and scipy.
if ! python3 -c "import numpy, scipy" 2>/dev/null; then
    echo "installing numpy and scipy for the SciPy peer check"
    python3 -m pip install --quiet --disable-pip-version-check numpy scipy
fi

cargo test --workspace --release
