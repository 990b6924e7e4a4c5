#!/usr/bin/env bash
# `make table2`: the paper's Table II. Trains the three variants (g_sac_cog, g_sac_nocog, s_sac)
# with the same budget and seed AT THE SAME TIME against ONE server and its one scenario pool
# (three trainers sharing a server), evaluates each on the test split, and writes
# out/table2/<variant>/eval.json plus docs/table2.json. Budget: TABLE2_FRAMES (default 12 000).
set -euo pipefail
cd "$(dirname "$0")/.."
server=target/release/sim-server
py=.venv/bin/python
frames=${TABLE2_FRAMES:-12000}
seed=${TABLE2_SEED:-0}
out=out/table2
rm -rf "$out"
mkdir -p "$out"
port=$("$py" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
endpoint="tcp/127.0.0.1:$port"
RUST_LOG=${RUST_LOG:-warn} "$server" serve --cfg "zenoh/listen/endpoints:[\"$endpoint\"]" \
    --cfg server_id:table2 > "$out/server.log" 2>&1 &
server_pid=$!
trap 'kill "$server_pid" 2>/dev/null; wait "$server_pid" 2>/dev/null || true' EXIT
remote=(env_backend=remote "server_endpoint=$endpoint" server_prefix=sharedspace)
start=$(date +%s)
pids=()
for variant in g_sac_cog g_sac_nocog s_sac; do
    "$py" -m sharedspace.train --set "variant=$variant" "seed=$seed" "total_frames=$frames" \
        init_random_frames=2000 num_envs=8 eval_interval=0 "checkpoint_interval=$frames" \
        progress=false "log_dir=$out/$variant" "${remote[@]}" > "$out/$variant.log" 2>&1 &
    pids+=($!)
done
for pid in "${pids[@]}"; do wait "$pid"; done
echo "trained 3 variants x $frames frames concurrently in $(( $(date +%s) - start )) s" | tee "$out/walltime.txt"
for variant in g_sac_cog g_sac_nocog s_sac; do
    echo "== $variant"
    "$py" -m sharedspace.train.evaluate --checkpoint "$out/$variant/checkpoints/last.pt" --split test \
        --json "$out/$variant/eval.json" --set "${remote[@]}"
done
