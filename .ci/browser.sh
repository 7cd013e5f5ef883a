#!/usr/bin/env bash
# Installs Debian's Chromium for the viewer's browser tests (tests/view/test_browser.py); they
# are skipped, with the reason, where no Chromium is found.  Idempotent: does nothing when a
# chromium is already on PATH.  Run as root (CI runs as root); called by .ci/run.
set -euo pipefail
if command -v chromium >/dev/null 2>&1; then
  echo "browser: $(chromium --version 2>/dev/null | head -1)"
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core >/dev/null
echo "browser: $(chromium --version 2>/dev/null | head -1)"
