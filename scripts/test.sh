#!/usr/bin/env bash
# The README's test command: installs what the tests need (Debian packages),
# starts the services they talk to (a one-node Slurm cluster, an S3 server),
# runs `cargo test --workspace "$@"`, and stops the services again.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

# Debian packages the tests drive: headless Chromium (HTML screenshots),
# TeX (LaTeX → PDF), poppler (PDF page count), PrusaSlicer (expands the
# Marlin K_A export's start-G-code conditionals).
need=()
command -v chromium >/dev/null || need+=(chromium)
command -v prusa-slicer >/dev/null || need+=(prusa-slicer)
command -v pdflatex >/dev/null || need+=(texlive-latex-base texlive-latex-recommended texlive-latex-extra)
command -v pdfinfo >/dev/null || need+=(poppler-utils)
for s in scripts/services/*.sh; do
    [ -e "$s" ] && while read -r p; do [ -n "$p" ] && need+=("$p"); done < <(bash "$s" packages)
done
if [ ${#need[@]} -gt 0 ]; then
    echo "test.sh: installing ${need[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >&2
    apt-get install -y -qq --no-install-recommends "${need[@]}" >&2
fi

# Services: each script `up DIR` starts one and writes DIR/env (exports the
# tests read); `down DIR` stops it. State lives under target/services.
svc_root="$root/target/services"
started=()
stop_all() {
    for s in "${started[@]}"; do bash "scripts/services/$s.sh" down "$svc_root/$s" || true; done
}
trap stop_all EXIT
for s in scripts/services/*.sh; do
    [ -e "$s" ] || continue
    name=$(basename "$s" .sh)
    mkdir -p "$svc_root/$name"
    bash "$s" up "$svc_root/$name"
    started+=("$name")
    # shellcheck disable=SC1090
    source "$svc_root/$name/env"
done

# No incremental caches unless asked for: on a clean build they only grow
# target/ (CI ran out of disk once). Set CARGO_INCREMENTAL=1 to keep them.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
cargo test --workspace "$@"
