#!/usr/bin/env bash
# Installs everything msflash needs on a Debian 12 machine into .venv/ (idempotent; safe to re-run).
#   1. apt packages for Aravis, GObject introspection and the booth firmware's AVR toolchain and
#      simulator (only those missing; needs root or sudo)
#   2. a Python virtual environment in .venv/ at the repository root
#   3. msflash itself (editable) with its test extras; the command lands at .venv/bin/msflash
set -euo pipefail
cd "$(dirname "$0")"

say() { printf 'setup: %s\n' "$*" >&2; }

APT_PACKAGES=(gir1.2-aravis-0.8 aravis-tools aravis-tools-cli libgirepository1.0-dev libcairo2-dev pkg-config
              gcc-avr avr-libc binutils-avr simavr libsimavr-dev make gcc  # booth firmware + its simavr tests
              avrdude  # flashing the booth (make -C led_controller/firmware flash; tested against the bootloader twin)
              chromium chromium-driver  # browser tests: msflash live's page and the run report (headless, Selenium)
              libimage-exiftool-perl)  # exiftool: the export tests validate every DNG with it
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
    sudo_cmd=()
    [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
    say "installing apt packages: ${missing[*]}"
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
else
    say "apt packages present: ${APT_PACKAGES[*]}"
fi

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    say "creating .venv with $($PYTHON --version)"
    "$PYTHON" -m venv .venv
fi
stamp=.venv/.msflash-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    say "installing msflash (editable) and its dependencies into .venv"
    .venv/bin/python -m pip install -q --upgrade pip >/dev/null
    .venv/bin/python -m pip install -q -e ".[test,study,fast]"
    touch "$stamp"
else
    say "msflash already installed in .venv (pyproject.toml unchanged)"
fi
say "ready: .venv/bin/msflash"
