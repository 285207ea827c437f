#!/usr/bin/env bash
# Copy the pinned three.js build into the viewer's static files (run once per version bump; the copied
# files are committed, so neither a build nor a network is needed to run or test the daemon).
# Needs npm (only to fetch the package tarball from the registry). See docs/viewer.md.
set -euo pipefail
THREE_VERSION="0.170.0"
cd "$(dirname "$0")/.."
dest=lidard/api/viewer/static/vendor
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && npm pack --silent "three@${THREE_VERSION}" >/dev/null && tar xzf "three-${THREE_VERSION}.tgz")
mkdir -p "$dest"
cp "$tmp/package/build/three.module.min.js" "$dest/three.module.min.js"
cp "$tmp/package/examples/jsm/controls/OrbitControls.js" "$dest/OrbitControls.js"
cp "$tmp/package/LICENSE" "$dest/three.LICENSE"
echo "three@${THREE_VERSION}" > "$dest/VERSION"
echo "vendored three@${THREE_VERSION} into $dest"
