#!/usr/bin/env bash
# The test command (README, .ci/run): installs what the tests need, then runs every check.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
scripts/check.sh
