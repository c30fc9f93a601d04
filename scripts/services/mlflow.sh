#!/usr/bin/env bash
# A real MLflow tracking server on loopback: PyPI's `mlflow` (pinned below)
# in a venv under DIR, a SQLite backend store and a local artifact root served
# through the server's artifact proxy (`--serve-artifacts`), so
# `fdmlab mlflow push` talks to it exactly as to a lab's server.
#   mlflow.sh packages   Debian packages it needs (python3-venv when missing)
#   mlflow.sh up DIR     start the server, wait until healthy, write DIR/env
#   mlflow.sh down DIR   stop the server by the PID it recorded
# The venv is installed with `uv` (itself from PyPI), which resolves and
# installs mlflow's ~100 wheels several times faster than pip.
set -euo pipefail

mlflow_version="3.17.2"
uv_version="0.13.9"

case "${1:-}" in
packages)
    python3 -c 'import venv, ensurepip' 2>/dev/null || echo python3-venv
    ;;
up)
    dir=$(realpath -m "${2:?usage: mlflow.sh up DIR}")
    mkdir -p "$dir"
    if [ ! -x "$dir/venv/bin/mlflow" ] || ! grep -qx "$mlflow_version" "$dir/venv/.mlflow-version" 2>/dev/null; then
        rm -rf "$dir/venv"
        python3 -m venv "$dir/venv"
        "$dir/venv/bin/pip" install -q "uv==$uv_version" >&2
        VIRTUAL_ENV="$dir/venv" "$dir/venv/bin/uv" pip install -q --python "$dir/venv/bin/python" "mlflow==$mlflow_version" >&2
        echo "$mlflow_version" >"$dir/venv/.mlflow-version"
    fi
    # Fresh state each start: tests must not see another run's experiments.
    rm -rf "$dir/state"
    mkdir -p "$dir/state/artifacts"
    port=$("$dir/venv/bin/python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    # One worker: the SQLite store is written by one process. No job runner
    # (MLflow's background jobs for GenAI features): it only slows the start.
    # Bytecode is written on the first start (only what the server imports),
    # so later starts skip compiling even where PYTHONDONTWRITEBYTECODE is set.
    env -u PYTHONDONTWRITEBYTECODE MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false setsid nohup "$dir/venv/bin/mlflow" server --host 127.0.0.1 --port "$port" --workers 1 \
        --backend-store-uri "sqlite:///$dir/state/mlflow.db" \
        --serve-artifacts --artifacts-destination "$dir/state/artifacts" \
        >"$dir/server.log" 2>&1 &
    echo $! >"$dir/server.pid"
    uri="http://127.0.0.1:$port"
    ready=
    for _ in $(seq 1 240); do
        if "$dir/venv/bin/python" -c 'import sys, urllib.request; urllib.request.urlopen(sys.argv[1] + "/health", timeout=2)' "$uri" 2>/dev/null; then
            ready=1
            break
        fi
        kill -0 "$(cat "$dir/server.pid")" 2>/dev/null || break
        sleep 0.25
    done
    if [ -z "$ready" ]; then
        echo "mlflow.sh: server at $uri did not become healthy in 60 s; log in $dir/server.log" >&2
        exit 1
    fi
    cat >"$dir/env" <<ENV
export MLFLOW_TRACKING_URI=$uri
ENV
    echo "mlflow.sh: MLflow $mlflow_version tracking server up at $uri" >&2
    ;;
down)
    dir=$(realpath -m "${2:?usage: mlflow.sh down DIR}")
    if [ -s "$dir/server.pid" ]; then
        pid=$(cat "$dir/server.pid")
        # `mlflow server` runs uvicorn/gunicorn as children: stop its process group.
        kill -- "-$pid" 2>/dev/null || kill "$pid" 2>/dev/null || true
        for _ in $(seq 1 20); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
        kill -9 -- "-$pid" 2>/dev/null || kill -9 "$pid" 2>/dev/null || true
        rm -f "$dir/server.pid"
    fi
    rm -f "$dir/env"
    ;;
*)
    echo "usage: mlflow.sh packages | up DIR | down DIR" >&2
    exit 2
    ;;
esac
