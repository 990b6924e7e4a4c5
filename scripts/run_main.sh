#!/usr/bin/env bash
# `make run`: the main job end to end on the embedded default scenario pool (no data files needed).
#
# 1. starts `sim-server serve` on a free loopback port (multicast scouting off), with the world
#    parameters of the paper's Table II runs (params/table2.json5);
# 2. records the demonstrations of the paper world's train scenes once (`make demos`' second
#    dataset, out/demos/table2, cached; docs/PRIOR_DATA.md), then trains a short G-SAC-Cog run
#    against the server over Zenoh from them: the actor cloned first, then RLPD batches (half
#    prior, half online) with a BC term (progress bar: steps/s, return, success);
# 3. evaluates the checkpoint on the test split and prints the paper's Table II columns next to
#    the recorded human driver;
# 4. writes plots (learning curves, speed/acceleration/heading profiles, a scene with its risk
#    graph) to out/main/plots;
# 5. evaluates the shipped G-SAC-Cog policy of the Table II runs
#    (results/table2/policies/g_sac_cog-s0.pt, docs/RESULTS.md) on the test split next to the
#    human driver: the real result, in a minute; then stops the server.
# Budget: RUN_FRAMES env transitions (default 6 000) after RUN_CLONE cloning steps (default
# 5 000): a few minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
server=target/release/sim-server
py=.venv/bin/python
frames=${RUN_FRAMES:-6000}
clone=${RUN_CLONE:-5000}
demos=out/demos/table2
out=out/main
rm -rf "$out"
mkdir -p "$out"

port=$("$py" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
endpoint="tcp/127.0.0.1:$port"
RUST_LOG=${RUST_LOG:-warn} "$server" serve --cfg "zenoh/listen/endpoints:[\"$endpoint\"]" \
    --cfg server_id:main --cfg 'params:"params/table2.json5"' > "$out/server.log" 2>&1 &
server_pid=$!
trap 'kill "$server_pid" 2>/dev/null; wait "$server_pid" 2>/dev/null || true' EXIT
echo "== sim-server serving on $endpoint (log: $out/server.log)"

remote=("server_endpoint=$endpoint" server_prefix=sharedspace)
echo "== demonstrations on the train scenes (cached in $demos)"
"$py" -m sharedspace.paper.demos --params params/table2.json5 --scale 4 --out "$demos"

echo "== training G-SAC-Cog from them: $clone cloning steps, then $frames frames against the server"
"$py" -m sharedspace.train --set variant=g_sac_cog "total_frames=$frames" init_random_frames=0 \
    server_params=params/table2.json5 "prior_data=$demos" "bc_steps=$clone" bc_weight=0.4 \
    critic_layer_norm=true critic_warmup=1000 utd_ratio=1 alpha_init=0.01 \
    num_envs=8 eval_interval=0 "checkpoint_interval=$frames" "log_dir=$out" "${remote[@]}"

echo
echo "== evaluation on the test split (paper Table II columns)"
"$py" -m sharedspace.paper.evaluate --checkpoint "$out/checkpoints/last.pt" --split test \
    --json "$out/eval.json" --set "${remote[@]}"

echo
echo "== plots -> $out/plots"
"$py" -m sharedspace.paper.plots --run "$out" --eval-json "$out/eval.json" --scene 2 --out "$out/plots"
ls "$out/plots"

shipped=results/table2/policies/g_sac_cog-s0.pt
if [ -f "$shipped" ]; then
    echo
    echo "== the shipped G-SAC-Cog policy of the Table II runs ($shipped, $("$py" -c \
        "import torch, sys; print(torch.load(sys.argv[1], weights_only=False)['counters']['frames'])" \
        "$shipped") frames) on the test split"
    "$py" -m sharedspace.paper.evaluate --checkpoint "$shipped" --split test \
        --json "$out/shipped_eval.json" --set "${remote[@]}"
else
    echo "no shipped policy at $shipped: \`make table2\` trains and ships it" >&2
    exit 1
fi
