#!/usr/bin/env bash
# `make run`: the main job on the embedded default scenario pool (no files needed).
#
# What it runs today: the pedestrian-model evaluation of the paper's Table I (cv, sfm, ra_sfm,
# cr_sfm on the test split, the AV replaying its record), and one rollout of the first test
# scenario with CR-SFM pedestrians written as JSON lines to out/. The remote SAC-GCN training
# loop joins this script when the trainer lands (issues 5-7).
set -euo pipefail
cd "$(dirname "$0")/.."
server=target/release/sim-server


mkdir -p out
echo "== Table I: pedestrian models on the test split of the embedded HBS pool"
"$server" eval-peds --split test --models cv,sfm,ra_sfm,cr_sfm --out out/table1.json
echo
echo "== rollout of one test scenario with CR-SFM pedestrians -> out/rollout.jsonl"
"$server" rollout --scenario 2 --model cr_sfm --av replay --out out/rollout.jsonl
echo "wrote out/table1.json and out/rollout.jsonl ($(wc -l < out/rollout.jsonl) lines; format in docs/ROLLOUT.md)"
