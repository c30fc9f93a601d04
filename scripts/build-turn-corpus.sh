#!/usr/bin/env bash
# Rebuild the turn corpus shipped in datasets/turns-corpus (issue #12 §4), or
# with --full the larger one (issue #25: more families and drawn settings),
# built outside the repository (default target/turn-corpus-full; ~2 min here).
#
#   scripts/build-turn-corpus.sh [--full] [--out DIR] [--seed N] [--arcs N] [--check]
#
# Installs the Debian slicers when missing (PrusaSlicer 2.5, Slic3r 1.3,
# CuraEngine 4.13 and the `cura` package for its printer definitions, OpenSCAD),
# then runs scripts/turn-corpus/build.py, which records generator, model
# parameters, slicer versions, settings and seed in manifest.json.
# --check rebuilds into a temporary folder and compares every file's hash.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
command -v prusa-slicer >/dev/null || need+=(prusa-slicer)
command -v slic3r >/dev/null || need+=(slic3r)
command -v CuraEngine >/dev/null || need+=(cura-engine)
[ -d /usr/share/cura/resources/definitions ] || need+=(cura)
command -v openscad >/dev/null || need+=(openscad)
if [ ${#need[@]} -gt 0 ]; then
    echo "installing: ${need[*]}" >&2
    apt-get update
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${need[@]}"
fi

exec nice -n 10 python3 scripts/turn-corpus/build.py "$@"
