#!/usr/bin/env bash
# Install everything the tests need on a fresh Debian machine and run them.
# The control-panel test drives a real headless Chromium: Debian's chromium and
# chromium-driver are installed when missing (as root, or with sudo).
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then
    if [ "$(id -u)" = 0 ]; then SUDO=""; elif command -v sudo >/dev/null; then SUDO="sudo"; else
        echo "the browser test needs Debian's chromium and chromium-driver: install them as root" >&2; exit 2; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium chromium-driver >/dev/null
fi
python3 -m venv .venv
.venv/bin/pip install -q -e '.[test]'
.venv/bin/python -m pytest "$@"
