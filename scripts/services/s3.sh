#!/usr/bin/env bash
# A real S3-compatible server on loopback: moto's server (PyPI `moto[server]`,
# pinned below) in a venv under DIR. It speaks the S3 REST API over HTTP, so
# the `object_store` client talks to it exactly as to AWS or MinIO.
#   s3.sh packages   Debian packages it needs (python3-venv when missing)
#   s3.sh up DIR     start the server, create the test bucket, write DIR/env
#   s3.sh down DIR   stop the server by the PID it recorded
set -euo pipefail

moto_version="5.2.1"
bucket=fdmlab-test

case "${1:-}" in
packages)
    python3 -c 'import venv, ensurepip' 2>/dev/null || echo python3-venv
    ;;
up)
    dir=$(realpath -m "${2:?usage: s3.sh up DIR}")
    mkdir -p "$dir"
    if [ ! -x "$dir/venv/bin/moto_server" ]; then
        python3 -m venv "$dir/venv"
        "$dir/venv/bin/pip" install -q "moto[server]==$moto_version" >&2
    fi
    port=$("$dir/venv/bin/python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    nohup "$dir/venv/bin/moto_server" -H 127.0.0.1 -p "$port" >"$dir/server.log" 2>&1 &
    echo $! >"$dir/server.pid"
    endpoint="http://127.0.0.1:$port"
    export AWS_ACCESS_KEY_ID=fdmlab-test AWS_SECRET_ACCESS_KEY=fdmlab-test-secret AWS_REGION=us-east-1
    ready=
    for _ in $(seq 1 120); do
        if "$dir/venv/bin/python" - "$endpoint" "$bucket" 2>/dev/null <<'EOF'; then
import sys, boto3
s3 = boto3.client("s3", endpoint_url=sys.argv[1])
s3.create_bucket(Bucket=sys.argv[2])
EOF
            ready=1
            break
        fi
        sleep 0.25
    done
    if [ -z "$ready" ]; then
        echo "s3.sh: server at $endpoint did not answer in 30 s; log in $dir/server.log" >&2
        exit 1
    fi
    cat >"$dir/env" <<EOF
export AWS_ENDPOINT_URL=$endpoint
export AWS_ACCESS_KEY_ID=$AWS_ACCESS_KEY_ID
export AWS_SECRET_ACCESS_KEY=$AWS_SECRET_ACCESS_KEY
export AWS_REGION=$AWS_REGION
export AWS_ALLOW_HTTP=true
export FDMLAB_TEST_S3_BUCKET=$bucket
EOF
    echo "s3.sh: moto S3 server up at $endpoint, bucket $bucket" >&2
    ;;
down)
    dir=$(realpath -m "${2:?usage: s3.sh down DIR}")
    if [ -s "$dir/server.pid" ]; then
        pid=$(cat "$dir/server.pid")
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 1 40); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
        kill -9 "$pid" 2>/dev/null || true
        rm -f "$dir/server.pid"
    fi
    rm -f "$dir/env"
    ;;
*)
    echo "usage: s3.sh packages | up DIR | down DIR" >&2
    exit 2
    ;;
esac
