#!/usr/bin/env bash
# Every check, on a machine that scripts/setup.sh has provisioned: formatting, lints, docs, the book
# and its links, both firmware images, firmware logic on the host, then every test of the workspace
# (the book's examples and its CLI reference among them).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
step() { echo; echo "== $*"; }

step "formatting (rustfmt.toml)"
cargo fmt --all --check

step "lints: the workspace (protocol, host, tests)"
cargo clippy --release --workspace --all-targets -- -D warnings

step "docs"
RUSTDOCFLAGS=-Dwarnings cargo doc --no-deps --workspace --quiet

step "the book (docs/): build it, then every link of it and of the README"
mdbook build docs
python3 scripts/check-links.py docs/book

step "both firmware images: the emulated controller and the real board"
cargo build-emulated
cargo build-stm32

step "firmware (its own workspace): fmt, clippy -D warnings for both boards, logic tests on the host"
scripts/firmware-check

step "every test of the workspace"
cargo test --workspace --release
