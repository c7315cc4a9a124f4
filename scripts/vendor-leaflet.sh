#!/usr/bin/env bash
# Re-vendors Leaflet (the map viewer library of `companion stitch`'s viewer.html) from the npm registry into
# companion/viewer/static/leaflet/: the minified JS, its CSS and images, and its licence. The viewer ships these
# files as package data, so nothing is fetched when a map is viewed. Run it only to move to another version:
#   scripts/vendor-leaflet.sh [VERSION]      (default: the version in companion/viewer/static/leaflet/VERSION)
# npm checks the tarball against the registry's integrity hash; its sha256 is recorded in VERSION beside it.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="$root/companion/viewer/static/leaflet"
version="${1:-$(sed -n 's/^leaflet \([0-9.]*\).*/\1/p' "$dest/VERSION")}"
command -v npm >/dev/null || { echo "error: npm not found. fix: apt-get install -y npm" >&2; exit 2; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent "leaflet@$version" >/dev/null && tar xzf "leaflet-$version.tgz")
rm -rf "$dest"
mkdir -p "$dest/images"
cp "$work/package/dist/leaflet.js" "$work/package/dist/leaflet.css" "$dest/"
cp "$work/package/dist/images/"*.png "$dest/images/"
cp "$work/package/LICENSE" "$dest/LICENSE"
sha="$(sha256sum "$work/leaflet-$version.tgz" | cut -d' ' -f1)"
printf 'leaflet %s (npm registry tarball leaflet-%s.tgz, sha256 %s)\nBSD-2-Clause: see LICENSE\n' \
    "$version" "$version" "$sha" > "$dest/VERSION"
echo "vendored leaflet $version into $dest"
