"""The TorchRL batch round trip of two builds side by side: a baseline checkout's Python package
and server against today's, in alternating blocks of one run (the host's speed swings 1.5-2x
within minutes, so only interleaved blocks compare).

    git worktree add ../old REV
    (cd ../old && CARGO_TARGET_DIR=../target-old cargo build --release -p sim-server)
    .venv/bin/python benchmarks/torchrl_ab.py --old ../old --old-server ../target-old/release/sim-server

Each block runs one process per build: ``RemoteBatchedEnv(num_envs=K, max_agents=8)`` of that
build's package against that build's server (both started here on free loopback ports),
``step_and_maybe_reset`` with random actions for ``--seconds``, the median env-steps/s of its
steps. Blocks run old/new/new/old. Prints each block and the per-block ratio new/old, and a
JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

WORKER = r"""
import json, statistics, sys, time
import torch
import sharedspace
from sharedspace.torchrl_env import RemoteBatchedEnv

endpoint, prefix, k, seconds = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
env = RemoteBatchedEnv(num_envs=k, max_agents=8, seed=0, endpoint=endpoint, prefix=prefix)
td = env.reset()
gen = torch.Generator().manual_seed(0)
times = []
deadline = time.perf_counter() + seconds
n = 0
while time.perf_counter() < deadline or n < 10:
    td["action"] = torch.rand(k, 2, generator=gen) * 2 - 1
    t0 = time.perf_counter()
    _, td = env.step_and_maybe_reset(td)
    if n >= 3:
        times.append(time.perf_counter() - t0)
    n += 1
env.close()
print(json.dumps({"package": sharedspace.__file__, "env_steps_per_s": k / statistics.median(times),
                  "steps": len(times)}))
"""


def start_server(binary: str, prefix: str) -> tuple[subprocess.Popen, str]:
    sys.path.insert(0, str(ROOT / "clients" / "src"))
    from sharedspace.local_server import free_port, wait_port

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen(
        [binary, "serve", "--cfg", f'zenoh/listen/endpoints:["{endpoint}"]', "--cfg",
         "zenoh/scouting/multicast/enabled:false", "--cfg", f"prefix:{prefix}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    wait_port(port, proc, 30.0)
    return proc, endpoint


def block(src: Path, endpoint: str, prefix: str, k: int, seconds: float) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src / "clients" / "src")}
    out = subprocess.run(
        [sys.executable, "-c", WORKER, endpoint, prefix, str(k), str(seconds)],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="checkout of the baseline")
    ap.add_argument(
        "--old-server", required=True, help="the baseline's release sim-server"
    )
    ap.add_argument(
        "--new-server", default=str(ROOT / "target" / "release" / "sim-server")
    )
    ap.add_argument("--k", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--rounds", type=int, default=4, help="old/new/new/old rounds")
    args = ap.parse_args()
    builds = {
        "old": (Path(args.old).resolve(), args.old_server),
        "new": (ROOT, args.new_server),
    }
    servers = {
        name: start_server(binary, f"ab{name}") for name, (_, binary) in builds.items()
    }
    rows: list[dict] = []
    try:
        for r in range(args.rounds):
            pair = {}
            for name in ("old", "new", "new", "old"):
                src = builds[name][0]
                res = block(src, servers[name][1], f"ab{name}", args.k, args.seconds)
                pair.setdefault(name, []).append(res["env_steps_per_s"])
                print(f"round {r} {name}: {res['env_steps_per_s']:.0f} env-steps/s "
                      f"({res['steps']} steps, {res['package']})", flush=True)  # fmt: skip
            rows.append({k: statistics.mean(v) for k, v in pair.items()})
    finally:
        for proc, _ in servers.values():
            proc.terminate()
            proc.wait(timeout=10)
    ratios = [row["new"] / row["old"] for row in rows]
    summary = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "k": args.k,
        "seconds": args.seconds,
        "old_env_steps_per_s": [round(r["old"]) for r in rows],
        "new_env_steps_per_s": [round(r["new"]) for r in rows],
        "ratio_new_over_old": [round(x, 3) for x in ratios],
        "ratio_median": round(statistics.median(ratios), 3),
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
