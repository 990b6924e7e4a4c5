#!/usr/bin/env bash
# `make table2`: the paper's Table II with seeds (docs/RESULTS.md).
#
# Trains every variant (g_sac_cog, g_sac_nocog, s_sac) for every seed with the same budget, all
# trainers AT THE SAME TIME against ONE server and its one scenario pool, evaluates each on the
# test split, then writes the table (python -m sharedspace.paper.table2): per variant the mean
# and spread over seeds, pooled Wilson intervals, paired per-scenario comparisons, the scripted
# drivers, the human driver and the paper's rows.
#
# Every run checkpoints (with its replay buffer) and this script resumes unfinished runs from
# their last checkpoint, so a budget can span several sittings: run it again with the same
# TABLE2_OUT. Finished runs are not trained again.
#
#   TABLE2_SEEDS     seeds (default "0 1 2")
#   TABLE2_FRAMES    env transitions per run (default 200000)
#   TABLE2_VARIANTS  variants (default "g_sac_cog g_sac_nocog s_sac")
#   TABLE2_OUT       run folder (default out/table2; large: replay buffers)
#   TABLE2_PARAMS    world parameters of the server (default params/table2.json5)
#   TABLE2_DEVICE    torch device of the trainers (default cpu; "cuda" where a GPU is present)
#   TABLE2_CKPT      frames between checkpoints (default 20000)
#   TABLE2_EVAL      frames between test-split evaluations logged as learning curves (default 50000)
#   TABLE2_DOC       markdown file whose table2 block is rewritten (default docs/RESULTS.md; "" = none)
#   TABLE2_TRAIN     0 = skip training, only evaluate and tabulate what is there (default 1)
#   TABLE2_POOL      training pool: "" = the paper pool (default); "paper+general" = the paper's train
#                    scenes plus every general-pool scene sharing no agent with a test scene
#                    (sharedspace.paper.pools), tested on the paper's test split; "general" = the
#                    crowded benchmark, Table II-G: `hbs-general`'s train split, tested on its 76
#                    test scenes, its other cars reactive (the pool's `idm`; `make table2g`)
#   TABLE2_SET       more TrainConfig overrides for new runs, space-separated KEY=VALUE (no spaces
#                    inside a value), e.g. "max_agents=10 variations={\"position_sigma\":0.5}"
#   TABLE2_SEARCH_ROUNDS  rounds of the planner-bound search per test scenario (default 8; 0 = none)
#   TABLE2_JSON      where the table's JSON goes (default docs/table2.json)
#   TABLE2_SHIP      folder for the trained policies (actor + config; default results/table2/policies;
#                    "" = none): `make run` evaluates results/table2/policies/g_sac_cog-s0.pt
set -euo pipefail
cd "$(dirname "$0")/.."
server=target/release/sim-server
py=.venv/bin/python
seeds=${TABLE2_SEEDS:-0 1 2}
frames=${TABLE2_FRAMES:-200000}
variants=${TABLE2_VARIANTS:-g_sac_cog g_sac_nocog s_sac}
out=${TABLE2_OUT:-out/table2}
params=${TABLE2_PARAMS:-params/table2.json5}
device=${TABLE2_DEVICE:-cpu}
ckpt_every=${TABLE2_CKPT:-20000}
eval_every=${TABLE2_EVAL:-50000}
doc=${TABLE2_DOC-docs/RESULTS.md}
ship=${TABLE2_SHIP-results/table2/policies}
json=${TABLE2_JSON:-docs/table2.json}
mkdir -p "$out"

# The general pool (hbs-general, scenarios/EXTRACTION.md) extracted to the file $1.
extract_general() {
    local csv
    csv=$(mktemp)
    gunzip -c scenarios/data/hbs.csv.gz > "$csv"
    cargo run --quiet --release -p scenarios --bin extract-hbs -- --csv "$csv" --pool general --out "$1"
    rm -f "$csv"
}

pools=()
train_pool=()
eval_pool=()  # the pool whose test split the table is on, when not the server's default
case "${TABLE2_POOL:-}" in
    "") ;;
    paper+general)
        pool_file="$out/pool-paper-plus-general.json"
        if [ ! -f "$pool_file" ]; then
            extract_general "$out/pool-general.json"
            "$py" -m sharedspace.paper.pools --general "$out/pool-general.json" --out "$pool_file"
        fi
        pools=(--cfg "pools:[\"embedded:hbs-paper\",\"$pool_file\"]")
        train_pool=("scenario_pool=$pool_file")
        ;;
    general)
        pool_file="$out/pool-general.json"
        [ -f "$pool_file" ] || extract_general "$pool_file"
        pools=(--cfg "pools:[\"$pool_file\"]")
        train_pool=("scenario_pool=$pool_file")
        eval_pool=("scenario_pool=$pool_file")
        ;;
    *) echo "TABLE2_POOL must be empty, paper+general or general, not ${TABLE2_POOL}" >&2; exit 2 ;;
esac

port=$("$py" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
endpoint="tcp/127.0.0.1:$port"
RUST_LOG=${RUST_LOG:-warn} "$server" serve --cfg "zenoh/listen/endpoints:[\"$endpoint\"]" \
    --cfg server_id:table2 --cfg "params:\"$params\"" "${pools[@]}" >> "$out/server.log" 2>&1 &
server_pid=$!
pids=()
cleanup() {
    for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
    kill "$server_pid" 2>/dev/null || true
    wait 2>/dev/null || true
}
trap cleanup EXIT
remote=("server_endpoint=$endpoint" server_prefix=sharedspace)

if [ "${TABLE2_TRAIN:-1}" = 1 ]; then
    start=$(date +%s)
    for seed in $seeds; do
        for variant in $variants; do
            run="$out/$variant-s$seed"
            last="$run/checkpoints/last.pt"
            args=(--set "${remote[@]}" "total_frames=$frames" "device=$device")
            if [ -f "$last" ]; then
                done_frames=$("$py" -c "import torch, sys; print(torch.load(sys.argv[1], weights_only=False)['counters']['frames'])" "$last")
                if [ "$done_frames" -ge "$frames" ]; then
                    echo "== $variant seed $seed: done ($done_frames frames)"
                    continue
                fi
                echo "== $variant seed $seed: resuming at $done_frames frames"
                args=(--resume "$last" "${args[@]}")
            else
                echo "== $variant seed $seed: training"
                args+=("variant=$variant" "seed=$seed" init_random_frames=2000 num_envs=8 "${train_pool[@]}"
                    "eval_interval=$eval_every" eval_split=test "checkpoint_interval=$ckpt_every" save_buffer=true
                    progress=false "log_dir=$run")
                # shellcheck disable=SC2206 # word splitting is the format of TABLE2_SET
                args+=(${TABLE2_SET:-})
            fi
            "$py" -m sharedspace.train "${args[@]}" >> "$out/$variant-s$seed.log" 2>&1 &
            pids+=($!)
        done
    done
    status=0
    for pid in "${pids[@]}"; do wait "$pid" || status=1; done
    pids=()
    echo "trained in $(( $(date +%s) - start )) s (this sitting)" | tee -a "$out/walltime.txt"
    [ "$status" = 0 ] || { echo "a trainer failed: see $out/*.log"; exit 1; }
fi

"$py" -m sharedspace.paper.table2 --runs "$out" --frames "$frames" --params "$params" \
    --search-rounds "${TABLE2_SEARCH_ROUNDS:-8}" \
    --json "$json" ${doc:+--doc "$doc"} ${ship:+--ship "$ship"} --set "${remote[@]}" "${eval_pool[@]}"
