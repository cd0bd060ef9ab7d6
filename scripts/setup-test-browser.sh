#!/usr/bin/env bash
# Installs Debian's chromium and chromium-driver for the viewer's browser test
# (tests/viewer/test_viewer.py). Where they cannot be installed (no apt-get, not root) it says so and
# exits 0: that test then skips with the reason. Used by .ci/run and the README's test command.
set -u
if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup-test-browser: no apt-get here; the viewer's browser test will skip" >&2
    exit 0
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO="sudo -n"
    else
        echo "setup-test-browser: not root and no password-less sudo; the viewer's browser test will skip" >&2
        exit 0
    fi
fi
export DEBIAN_FRONTEND=noninteractive
if ! { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends chromium chromium-driver; } >/dev/null 2>&1; then
    echo "setup-test-browser: could not install chromium and chromium-driver; the viewer's browser test will skip" >&2
fi
exit 0
