#!/usr/bin/env bash
# Put weights/tpnet-m3.h5 and weights/tpnet-m5.h5 back, bit-identical, from the repository's git
# history (they are shipped but not tracked: weights/README.md, "What git tracks").
#
#   bash tools/restore_weights.sh [DEST]      # DEST: default weights/ (git ignores them there)
#
# Needs a clone with history (not --depth 1). Each file is checked against its SHA-256 below.
set -euo pipefail
REPO=$(cd "$(dirname "$0")/.." && pwd)
DEST=${1:-$REPO/weights}
# the last commit that tracked each of them and its SHA-256
declare -A COMMIT=(
  [tpnet-m3.h5]=5490d2ffc37bc662fdb88be7680d89f1c3ea5559
  [tpnet-m5.h5]=eb1a13ea00497542d2eafe65d48fe34e37c230ea
)
declare -A SHA=(
  [tpnet-m3.h5]=d565fa2efe5963da914a8047d63613e00298af4dd7940592faeab433286ecc49
  [tpnet-m5.h5]=3ada7c653f4929d75088f46e46a1baff87284cdf5b57d8ff5dce2eec38ed26ee
)
mkdir -p "$DEST"
for f in tpnet-m3.h5 tpnet-m5.h5; do
    if [ ! -f "$DEST/$f" ] || [ "$(sha256sum < "$DEST/$f" | cut -d' ' -f1)" != "${SHA[$f]}" ]; then
        c=${COMMIT[$f]}
        git -C "$REPO" cat-file -e "$c^{commit}" 2>/dev/null || {
            echo "restore_weights: commit $c is not in this clone's history (a shallow clone?): fetch it, e.g. git fetch --unshallow" >&2; exit 1; }
        git -C "$REPO" show "$c:weights/$f" > "$DEST/$f.tmp"
        mv "$DEST/$f.tmp" "$DEST/$f"
    fi
    got=$(sha256sum < "$DEST/$f" | cut -d' ' -f1)
    [ "$got" = "${SHA[$f]}" ] || { echo "restore_weights: $DEST/$f has SHA-256 $got, expected ${SHA[$f]}" >&2; exit 1; }
    echo "$DEST/$f: ok"
done
