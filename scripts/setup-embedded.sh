#!/usr/bin/env bash
# Installs what the controller firmware and the emulated controller need (sourced by the
# README's two commands): the thumbv7em target and qemu-system-arm.
rustup target add thumbv7em-none-eabihf >/dev/null
if ! command -v qemu-system-arm >/dev/null; then
    echo "installing qemu-system-arm"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq qemu-system-arm >/dev/null
fi
