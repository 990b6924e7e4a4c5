"""Python client round trips against the sharedspace server, next to a bare zenoh get/reply.

In one run, against one release ``sim-server serve`` (started here on a free loopback port,
multicast scouting off, unless ``--endpoint`` names a running one):

1. **single-env step** (measured interleaved with 2.): ``SimClient.step`` of one env (``[1, 2]`` float32 action in, decoded
   ``StepResult`` out), round-trip time per step;
2. **bare zenoh-python get/reply** with the same payload sizes: a zenoh-python queryable in a
   separate process (also over TCP loopback) answers a canned payload as long as the step reply
   to a query as long as the step request; the ratio step / bare is the client + server
   overhead over the transport (target <= 1.3);
3. **batch K=256**: ``VectorClient.step`` (one ``BatchStep`` of 256 envs with autoreset),
   env-steps per second (target >= 100 000);
4. **RemoteBatchedEnv vs LocalBatchedEnv** (TorchRL, ``step_and_maybe_reset`` with random
   actions, same K): env-steps per second of each (the remote one must be faster).

Usage: python benchmarks/client_roundtrip.py [--server target/release/sim-server] [--seconds 3]
Prints a table and a JSON line.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "clients" / "src"))

from sharedspace.wire import envelope, requests  # noqa: E402
from sharedspace.client import SimClient  # noqa: E402
from sharedspace.vector import VectorClient  # noqa: E402
from sharedspace.local_server import free_port, wait_port  # noqa: E402, F401 - soak, viewer_cost


def bare_server(port: int, reply_size: int) -> None:
    """The bare zenoh-python queryable (run in a child process)."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    payload = os.urandom(reply_size)
    session = zenoh.open(conf)

    def on_query(q):
        q.reply(q.key_expr, payload)

    qable = session.declare_queryable("benchmarks/bare", on_query)
    signal.sigwait({signal.SIGTERM, signal.SIGINT})
    qable.undeclare()
    session.close()


def timed_loop(fn, seconds: float, min_iter: int = 50) -> list[float]:
    times = []
    end = time.perf_counter() + seconds
    while time.perf_counter() < end or len(times) < min_iter:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def start_bare(reply_size: int):
    """The bare queryable process and a zenoh session connected to it; returns (proc, get)."""
    import zenoh

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, __file__, "--bare-server", str(port), str(reply_size)]
    )
    wait_port(port, proc, 30.0)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    def get(payload: bytes) -> bytes:
        h = session.get(
            "benchmarks/bare",
            payload=payload,
            timeout=5.0,
            consolidation=zenoh.ConsolidationMode.NONE,
        )
        return h.recv().ok.payload.to_bytes()

    deadline = time.monotonic() + 10
    while True:
        try:
            if len(get(b"x")) == reply_size:
                break
        except Exception:  # noqa: BLE001 - not routed yet
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    return proc, session, get


def bench_single(client: SimClient, seconds: float) -> tuple[dict, dict]:
    """Client step, the same step as bytes only, an info query and the bare get/reply, measured
    interleaved (A, B, C, D, A, B, ...) so that other load on the machine hits all alike."""
    env = client.create(1, seed=0, autoreset=True, max_agents=8)["env_ids"][0]
    client.reset(env)
    act = np.zeros((1, 2), np.float32)
    for _ in range(50):
        client.step(env, act)
    step_payload = envelope.encode({"actions": act})
    key = client.transport.key("server", client.env_server[env], "env", env, "step")
    reply_size = len(client.transport.query(key, step_payload))
    info_key = client.transport.key("server", client.env_server[env], "info")
    info_payload = requests.encode_info_request()
    proc, session, bare_get = start_bare(reply_size)
    bare_payload = os.urandom(len(step_payload))
    fns = {
        "step": lambda: client.step(env, act),
        "raw": lambda: client.transport.query(key, step_payload),
        "info": lambda: client.transport.query(info_key, info_payload),
        "bare": lambda: bare_get(bare_payload),
    }
    times: dict[str, list[float]] = {k: [] for k in fns}
    try:
        for _ in range(50):
            for f in fns.values():
                f()
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            for name, f in fns.items():
                t0 = time.perf_counter()
                f()
                times[name].append(time.perf_counter() - t0)
    finally:
        session.close()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
    client.close(env)
    med = {k: statistics.median(v) for k, v in times.items()}
    single = {
        "rtt_s": med["step"],
        "mean_s": statistics.fmean(times["step"]),
        "raw_step_rtt_s": med["raw"],
        "info_rtt_s": med["info"],
        "n": len(times["step"]),
        "request_bytes": len(step_payload),
        "reply_bytes": reply_size,
    }
    bare = {
        "rtt_s": med["bare"],
        "mean_s": statistics.fmean(times["bare"]),
        "n": len(times["bare"]),
    }
    return single, bare


def bench_batch(client: SimClient, k: int, seconds: float) -> dict:
    vec = VectorClient(k, client=client, seed=0, autoreset=True, max_agents=8)
    vec.reset()
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (16, k, 1, 2)).astype(np.float32)
    i = [0]

    def once():
        vec.step(acts[i[0] % 16])
        i[0] += 1

    for _ in range(5):
        once()
    times = timed_loop(once, seconds, min_iter=20)
    vec.close()
    per = statistics.median(times)
    return {
        "k": k,
        "step_s": per,
        "env_steps_per_s": k / per,
        "env_steps_per_s_mean": k / statistics.fmean(times),
        "n": len(times),
    }


def bench_torchrl(client: SimClient, k: int, seconds: float) -> dict:
    import torch

    from sharedspace.torchrl_env import RemoteBatchedEnv

    # The in-process numpy twin of the env is a test oracle, not part of the package.
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "clients" / "tests"))
    from local_env import LocalBatchedEnv

    out = {}
    for name, make in (
        (
            "remote",
            lambda: RemoteBatchedEnv(num_envs=k, max_agents=8, seed=0, client=client),
        ),
        ("local", lambda: LocalBatchedEnv(num_envs=k, max_agents=8, seed=0)),
    ):
        env = make()
        td = env.reset()
        gen = torch.Generator().manual_seed(0)

        def once(env=env, gen=gen):
            nonlocal td
            td["action"] = torch.rand(k, 2, generator=gen) * 2 - 1
            _, td = env.step_and_maybe_reset(td)

        for _ in range(3):
            once()
        times = timed_loop(once, seconds, min_iter=10)
        env.close()
        out[name] = {
            "step_s": statistics.median(times),
            "env_steps_per_s": k / statistics.median(times),
            "n": len(times),
        }
    out["k"] = k
    out["speedup_remote_over_local"] = (
        out["remote"]["env_steps_per_s"] / out["local"]["env_steps_per_s"]
    )
    return out


def main(argv=None) -> int:
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "--bare-server":
        bare_server(int(sys.argv[2]), int(sys.argv[3]))
        return 0
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--server", default=str(ROOT / "target" / "release" / "sim-server"))
    ap.add_argument("--endpoint", default="", help="use a running server instead")
    ap.add_argument("--prefix", default="benchrt")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--k", type=int, default=256)
    ap.add_argument("--torchrl-k", type=int, default=16)
    args = ap.parse_args(argv)

    proc = None
    endpoint = args.endpoint
    if not endpoint:
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        proc = subprocess.Popen(
            [
                args.server,
                "serve",
                "--cfg",
                f'zenoh/listen/endpoints:["{endpoint}"]',
                "--cfg",
                f"prefix:{args.prefix}",
                "--cfg",
                "server_id:bench",
            ],
            env={**os.environ, "RUST_LOG": "warn"},
        )
        wait_port(port, proc, 30.0)
    try:
        client = SimClient(endpoint, args.prefix, timeout=10.0)
        client.servers(timeout=10.0)
        single, bare = bench_single(client, args.seconds)
        batch = bench_batch(client, args.k, args.seconds)
        trl = bench_torchrl(client, args.torchrl_k, args.seconds)
        client.shutdown()
    finally:
        if proc is not None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)

    ratio = single["rtt_s"] / bare["rtt_s"]
    print(
        f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}, "
        f"host: {platform.node()}, cpus: {os.cpu_count()}, python {platform.python_version()}"
    )
    print(
        f"single-env step RTT     : {single['rtt_s'] * 1e6:8.1f} us (median of {single['n']}; "
        f"request {single['request_bytes']} B, reply {single['reply_bytes']} B)"
    )
    print(
        f"bare zenoh get/reply    : {bare['rtt_s'] * 1e6:8.1f} us (median of {bare['n']})"
    )
    print(
        f"  same step, bytes only : {single['raw_step_rtt_s'] * 1e6:8.1f} us (transport + server, "
        "no client encode/decode)"
    )
    print(f"  info query (no sim)   : {single['info_rtt_s'] * 1e6:8.1f} us")
    print(f"ratio step / bare       : {ratio:8.2f}   (target <= 1.3)")
    print(
        f"batch K={batch['k']} step       : {batch['step_s'] * 1e3:8.2f} ms -> "
        f"{batch['env_steps_per_s']:,.0f} env-steps/s (target >= 100,000)"
    )
    print(
        f"TorchRL K={trl['k']} remote     : {trl['remote']['env_steps_per_s']:,.0f} env-steps/s"
    )
    print(
        f"TorchRL K={trl['k']} local numpy: {trl['local']['env_steps_per_s']:,.0f} env-steps/s "
        f"(remote x{trl['speedup_remote_over_local']:.1f})"
    )
    print(
        json.dumps(
            {
                "single": single,
                "bare": bare,
                "ratio": ratio,
                "batch": batch,
                "torchrl": trl,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
