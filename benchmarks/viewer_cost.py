"""What watching costs training: env-steps/s of a batched client with and without the live
browser viewer attached, side by side in one run (docs/BENCHMARKS.md, docs/VIEWER.md).

One release ``sim-server serve`` on a free loopback port; a ``VectorClient`` of K envs
(autoreset, random actions) steps as fast as it can. The viewer (``sharedspace.viewer.Viewer``:
the router with the remote-api plugin, and the page in headless Chromium) runs the whole time;
in "attached" rounds the page follows the batch's first env (it subscribes to that env's
states, risk_graph and events), in "detached" rounds it shows about:blank (no subscription).
Rounds alternate, detached first, so drift on a shared machine hits both alike.

A second table isolates the server's side: a zenoh subscriber (``sharedspace.observer``, no
browser) to the states and risk graph of the batch's first env, of an env outside the batch,
and of every env (``env_id="*"``), against none; the server publishes only the envs somebody
subscribes to (per-env gates, sim-server/src/server/net.rs ``EnvWatch``). With
``--baseline-server`` another build (e.g. one gated per topic only) runs beside it, rounds
interleaved.

Usage: python benchmarks/viewer_cost.py [--k 8 256] [--rounds 4] [--seconds 5]
Prints a table and a JSON line.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "clients" / "src"))
sys.path.insert(0, str(ROOT / "bench"))

from client_roundtrip import free_port, wait_port  # noqa: E402

from sharedspace.client import SimClient  # noqa: E402
from sharedspace.vector import VectorClient  # noqa: E402
from sharedspace.observer import Observer  # noqa: E402
from sharedspace.viewer import Viewer  # noqa: E402


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium")
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--window-size=1280,760",
    ):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)


def frames_shown(driver) -> int:
    return int(
        driver.execute_script(
            "return document.getElementById('episode').dataset.frames"
        )
        or 0
    )


def steps_per_s(vec: VectorClient, k: int, seconds: float, acts: np.ndarray) -> float:
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        vec.step(acts[n % len(acts)])
        n += 1
    return n * k / (time.perf_counter() - t0)


def start_server(binary: str, prefix: str) -> tuple[subprocess.Popen, str]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen(
        [
            binary,
            "serve",
            "--cfg",
            f'zenoh/listen/endpoints:["{endpoint}"]',
            "--cfg",
            f"prefix:{prefix}",
            "--cfg",
            "server_id:bench",
        ],
        env={**os.environ, "RUST_LOG": "warn"},
    )
    wait_port(port, proc, 30.0)
    return proc, endpoint


def subscriber_table(
    servers: dict[str, str], k: int, rounds: int, seconds: float
) -> dict:
    """Per server binary (label -> path; rounds interleaved across them): median env-steps/s of
    a K-env batch with no subscriber, one to the batch's first env, one to an env outside the
    batch, and one to every env; and the messages each subscriber received per second."""
    setups = {}
    for label, binary in servers.items():
        prefix = f"benchsub{len(setups)}"
        proc, endpoint = start_server(binary, prefix)
        client = SimClient(endpoint, prefix, timeout=10.0)
        client.servers(timeout=10.0)
        vec = VectorClient(k, client=client, seed=0, autoreset=True, max_agents=8)
        vec.reset()
        other = client.create(1)["env_ids"][0]
        targets = {
            "none": None,
            "first env": vec.env_ids[0],
            "other env": other,
            "every env": "*",
        }
        setups[label] = (proc, endpoint, prefix, client, vec, targets)
    acts = np.random.default_rng(0).uniform(-1, 1, (16, k, 1, 2)).astype(np.float32)
    rates: dict = {}
    msgs: dict = {}
    try:
        for _ in range(rounds):
            for label, (_, endpoint, prefix, _, vec, targets) in setups.items():
                for cond, env_id in targets.items():
                    count = [0]
                    obs = None
                    if env_id is not None:
                        obs = Observer(
                            endpoint,
                            prefix,
                            env_id=env_id,
                            topics=("states", "risk_graph"),
                            callback=lambda _m, c=count: c.__setitem__(0, c[0] + 1),
                        )
                        time.sleep(
                            1.0
                        )  # subscribed, and the server's per-env gates in step
                    count[0] = 0
                    rates.setdefault((label, cond), []).append(
                        steps_per_s(vec, k, seconds, acts)
                    )
                    msgs.setdefault((label, cond), []).append(count[0] / seconds)
                    if obs is not None:
                        obs.close()
    finally:
        for proc, _, _, client, vec, _ in setups.values():
            vec.close()
            client.shutdown()
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
    return {
        f"{label} / {cond}": {
            "env_steps_per_s": statistics.median(rates[(label, cond)]),
            "msgs_per_s": statistics.median(msgs[(label, cond)]),
        }
        for (label, cond) in rates
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--server", default=str(ROOT / "target" / "release" / "sim-server"))
    ap.add_argument("--k", type=int, nargs="+", default=[8, 256], help="batch sizes")
    ap.add_argument("--rounds", type=int, default=4, help="rounds of each condition")
    ap.add_argument("--seconds", type=float, default=5.0, help="seconds per round")
    ap.add_argument(
        "--baseline-server",
        default="",
        help="another sim-server build for the subscriber table, measured in the same rounds",
    )
    args = ap.parse_args(argv)
    os.environ.setdefault("SHAREDSPACE_SIM_SERVER", args.server)

    prefix = "benchview"
    server, endpoint = start_server(args.server, prefix)
    results = []
    try:
        client = SimClient(endpoint, prefix, timeout=10.0)
        client.servers(timeout=10.0)
        with Viewer(endpoint, prefix) as viewer:
            driver = browser()
            try:
                for k in args.k:
                    vec = VectorClient(
                        k, client=client, seed=0, autoreset=True, max_agents=8
                    )
                    vec.reset()
                    acts = np.random.default_rng(0).uniform(-1, 1, (16, k, 1, 2))
                    acts = acts.astype(np.float32)
                    first_env = vec.env_ids[0]
                    runs = {"detached": [], "attached": []}
                    shown = []
                    for _ in range(args.rounds):
                        for cond in ("detached", "attached"):
                            if cond == "attached":
                                driver.get(viewer.url(env_id=first_env))
                                time.sleep(2.0)  # connected and subscribed
                                before = frames_shown(driver)
                            else:
                                driver.get("about:blank")
                                time.sleep(2.0)
                            runs[cond].append(steps_per_s(vec, k, args.seconds, acts))
                            if cond == "attached":
                                shown.append(
                                    (frames_shown(driver) - before) / args.seconds
                                )
                    vec.close()
                    med = {c: statistics.median(v) for c, v in runs.items()}
                    results.append(
                        {
                            "k": k,
                            "detached_env_steps_per_s": runs["detached"],
                            "attached_env_steps_per_s": runs["attached"],
                            "median_detached": med["detached"],
                            "median_attached": med["attached"],
                            "attached_over_detached": med["attached"] / med["detached"],
                            "frames_drawn_per_s": statistics.median(shown),
                        }
                    )
            finally:
                driver.quit()
        client.shutdown()
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=10)

    print(
        f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}, "
        f"host: {platform.node()}, cpus: {os.cpu_count()}, {platform.processor() or ''}"
    )
    print(
        "| K | env-steps/s, no viewer | env-steps/s, viewer attached | ratio | frames drawn/s |"
    )
    print("|---:|---:|---:|---:|---:|")
    for r in results:
        print(
            f"| {r['k']} | {r['median_detached']:,.0f} | {r['median_attached']:,.0f} | "
            f"{r['attached_over_detached']:.3f} | {r['frames_drawn_per_s']:.1f} |"
        )
    servers = {"this server": args.server}
    if args.baseline_server:
        servers = {"baseline": args.baseline_server, **servers}
    print()
    print("| K | server / subscriber | env-steps/s | messages/s received |")
    print("|---:|---|---:|---:|")
    for k in args.k:
        table = subscriber_table(servers, k, args.rounds, args.seconds)
        for r in results:
            if r["k"] == k:
                r["subscriber"] = table
        for cond, v in table.items():
            print(
                f"| {k} | {cond} | {v['env_steps_per_s']:,.0f} | {v['msgs_per_s']:,.0f} |"
            )
    print(json.dumps({"viewer_cost": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
