#!/usr/bin/env bash
# `make run`: the main job end to end on the embedded default scenario pool (no data files needed
# for its demo), in a few minutes on 2 cores.
#
# 1. starts `sim-server serve` on a free loopback port (multicast scouting off), with the world
#    parameters of the paper's Table II (params/table2.json5);
# 2. trains the fast learner for the benchmark's `paper` task against it over Zenoh: PPO with the
#    GCN over the risk graph, from scratch, on 256 envs stepped together, with the from-scratch
#    recipe of the benchmark's rows (sharedspace.arms.rows.ARMS["scratch"]: the learning rate
#    held for half the run, then falling to 0, so that the last checkpoint is the policy;
#    RUN_FRAMES frames, default 786 432: about 2 minutes; progress bar: frames/s, return,
#    success, the env's share of the time; curves on the validation scenes carved from the
#    train scenes);
# 3. evaluates its last checkpoint on the 18 test scenes (the paper's Table II columns, next to
#    the recorded human driver) and plots its curves, profiles and a scene with its risk graph
#    (out/main/plots);
# 4. scores the shipped best policies of the benchmark's `paper` and `crowd` tasks
#    (results/bench/best.json, docs/RESULTS.md) with `python -m sharedspace.bench`, each against
#    the task's car-aware script: the real result. `crowd` needs its pool, which `make run`
#    extracts first (out/table2g/pool-general.json).
set -euo pipefail
cd "$(dirname "$0")/.."
server=target/release/sim-server
py=.venv/bin/python
frames=${RUN_FRAMES:-786432}
out=out/main
rm -rf "$out"
mkdir -p "$out"

port=$("$py" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
endpoint="tcp/127.0.0.1:$port"
# The embedded pools: the trainer's validation split (task=paper) is a selection of the paper
# pool's train scenes it asks for by name, so that the run's curves never touch test scenes.
RUST_LOG=${RUST_LOG:-warn} "$server" serve --cfg "zenoh/listen/endpoints:[\"$endpoint\"]" \
    --cfg server_id:main --cfg 'params:"params/table2.json5"' \
    --cfg 'pools:["embedded:hbs-paper","embedded:hbs-general"]' > "$out/server.log" 2>&1 &
server_pid=$!
trap 'kill "$server_pid" 2>/dev/null; wait "$server_pid" 2>/dev/null || true' EXIT
echo "== sim-server serving on $endpoint (log: $out/server.log)"

remote=("server_endpoint=$endpoint" server_prefix=sharedspace)
mapfile -t recipe < <("$py" -c 'from sharedspace.arms.rows import ARMS; print(*ARMS["scratch"], sep="\n")')
echo "== training PPO-GCN-Cog from scratch (${recipe[*]}): $frames frames against the server"
"$py" -m sharedspace.train --set algorithm=ppo task=paper network=gcn_risk "total_frames=$frames" \
    "${recipe[@]}" eval_interval=262144 "checkpoint_interval=$frames" progress=true "log_dir=$out" \
    "${remote[@]}"

echo
echo "== its last checkpoint on the test split (paper Table II columns)"
"$py" -m sharedspace.paper.evaluate --checkpoint "$out/checkpoints/last.pt" --split test \
    --json "$out/eval.json" --set "${remote[@]}"

echo
echo "== plots -> $out/plots"
"$py" -m sharedspace.paper.plots --run "$out" --eval-json "$out/eval.json" --scene 2 --out "$out/plots"
ls "$out/plots"

best=results/bench/best.json
for task in paper crowd; do
    echo
    mapfile -t policies < <("$py" -c 'import json, sys; [print(p) for p in json.load(open(sys.argv[1]))[sys.argv[2]]["policies"]]' "$best" "$task")
    name=$("$py" -c 'import json, sys; print(json.load(open(sys.argv[1]))[sys.argv[2]]["name"])' "$best" "$task")
    echo "== the benchmark: the shipped best row of \`$task\` ($name, ${#policies[@]} seeds pooled) against car_aware"
    args=()
    for p in "${policies[@]}"; do args+=(--policy "$p"); done
    "$py" -m sharedspace.bench "$task" "${args[@]}" --name "$name" \
        --reference "results/bench/$task/car_aware.json"
done
