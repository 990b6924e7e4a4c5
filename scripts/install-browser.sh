#!/usr/bin/env bash
# Debian's chromium and chromium-driver for the viewer's browser test (clients/tests/test_viewer.py);
# `make test` runs this when either is missing. Uses sudo when not root.
set -euo pipefail
if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then
    exit 0
fi
if ! command -v apt-get >/dev/null; then
    echo "install chromium and its chromedriver (the viewer's browser test needs both)" >&2
    exit 1
fi
sudo=""
[ "$(id -u)" = 0 ] || sudo=sudo
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends chromium chromium-driver
