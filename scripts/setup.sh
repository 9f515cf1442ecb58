#!/usr/bin/env bash
# Provisioning for the tests (sourced or run by scripts/test.sh): the firmware target, the emulator
# the end-to-end tests boot, numpy/scipy for the SciPy peer check, pinocchio for the public-arm peer
# (bench/pinocchio_peer.py), g++ with Ceres Solver and nlohmann-json for the Ceres peer
# (bench/ceres/), the OpenIGTLink peers (the C++ library and pyigtl), and mdBook for the book.
# Safe to run again.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup-embedded.sh
if ! python3 -c "import numpy, scipy" 2>/dev/null; then
    echo "installing numpy and scipy for the SciPy peer check"
    python3 -m pip install --quiet --disable-pip-version-check numpy scipy
fi
if ! command -v g++ >/dev/null || [ ! -f /usr/include/ceres/ceres.h ] || [ ! -f /usr/include/nlohmann/json.hpp ] \
    || [ ! -e /usr/include/openigtlink/igtlTransformMessage.h ]; then
    echo "installing g++, libceres-dev, nlohmann-json3-dev and libopenigtlink-dev for the C++ peers"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq g++ libceres-dev nlohmann-json3-dev libopenigtlink-dev >/dev/null
fi
for module in pinocchio:pin pyigtl:pyigtl; do
    if ! python3 -c "import ${module%%:*}" 2>/dev/null; then
        echo "installing ${module#*:} (pip) for the peer tests"
        python3 -m pip install --quiet --disable-pip-version-check "${module#*:}"
    fi
done
MDBOOK_VERSION=0.5.4
if [ "$(mdbook --version 2>/dev/null)" != "mdbook v$MDBOOK_VERSION" ]; then
    echo "installing mdbook $MDBOOK_VERSION for the book (a few minutes, once)"
    cargo install --quiet --locked mdbook --version "$MDBOOK_VERSION" --no-default-features --features search
fi
