#!/usr/bin/env bash
# Runs a command next to a fresh `sim-server serve` on a free loopback port, then stops the
# server. The command sees the endpoint in $SHAREDSPACE_ENDPOINT (prefix `sharedspace`). The server
# serves the embedded pools (a trainer's validation split is a selection of their train scenes
# it asks for by name).
# Usage: scripts/with_server.sh COMMAND [ARGS...]
set -euo pipefail
cd "$(dirname "$0")/.."
server=target/release/sim-server
port=$(.venv/bin/python -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export SHAREDSPACE_ENDPOINT="tcp/127.0.0.1:$port"
mkdir -p out
RUST_LOG=${RUST_LOG:-warn} "$server" serve --cfg "zenoh/listen/endpoints:[\"$SHAREDSPACE_ENDPOINT\"]" \
    --cfg 'pools:["embedded:hbs-paper","embedded:hbs-general"]' \
    > out/server-$port.log 2>&1 &
server_pid=$!
trap 'kill "$server_pid" 2>/dev/null; wait "$server_pid" 2>/dev/null || true' EXIT
echo "sim-server serving on $SHAREDSPACE_ENDPOINT (log: out/server-$port.log)" >&2
"$@"
