#!/usr/bin/env bash
# Rebuilds three.min.js: the parts of three.js the viewer uses (three-entry.js), bundled and
# minified into one script that defines the global THREE (no network at view time).
# three 0.187.0 (MIT, LICENSE-three), esbuild 0.25; both from the npm registry.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
npm init -y >/dev/null
npm install --no-audit --no-fund three@0.187.0 esbuild@0.25 >/dev/null
cp "$here/three-entry.js" entry.js
npx esbuild entry.js --bundle --minify --format=iife --global-name=THREE \
  --outfile="$here/three.min.js"
cp node_modules/three/LICENSE "$here/LICENSE-three"
ls -l "$here/three.min.js"
