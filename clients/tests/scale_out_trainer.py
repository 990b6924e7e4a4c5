"""Trainer process of tests/test_scale_out.py (not a test module: run as a script).

Opens ``VectorClient(K, failover=True)`` in zenoh client mode through a router, steps ``--steps``
times with deterministic actions and writes a JSON result (``--out``): the server used before
and after, the failover count and the trajectory (per step: rewards, flags, env episode/step
and a checksum of the observations). With ``--pause-at N`` it stops after N steps, writes
``--paused-file`` (JSON with its server id) and waits for ``--go-file`` before going on, so
that the test can kill a server while the trainer is mid-run. Every wait is bounded.

Actions depend only on ``t``, the number of steps since the envs were (re)created: after a
failover (the scenario sequence restarts from the seed) the trajectory restarts too, so it can
be compared with the one before the loss.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
import traceback

import numpy as np

from sharedspace.vector import VectorClient


def _digest(obs) -> str:
    h = hashlib.sha1()
    for key in ("features", "adjacency", "mask", "node_ids"):
        h.update(np.ascontiguousarray(obs[key]).tobytes())
    return h.hexdigest()


def _reset_digests(res, k: int) -> list:
    """Per env: the digest of its new episode's first observation, or None (no autoreset)."""
    out: list = [None] * k
    resets = res["resets"]
    for j, i in enumerate(resets["index"]):
        out[int(i)] = _digest({key: v[j] for key, v in resets["obs"].items()})
    return out


def _actions(t: int, k: int, n_ext: int) -> np.ndarray:
    a = np.zeros((k, n_ext, 2), np.float32)
    for i in range(k):
        a[i, :, 0] = np.sin(0.37 * t + i)
        a[i, :, 1] = 0.5 * np.cos(0.11 * t)
    return a


def _write_json(path: str, data) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f)
    os.replace(tmp, path)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--endpoint", required=True)
    ap.add_argument("--prefix", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--envs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--pause-at", type=int, default=-1)
    ap.add_argument("--paused-file", default="")
    ap.add_argument("--go-file", default="")
    ap.add_argument("--wait", type=float, default=30.0)
    args = ap.parse_args()

    result = {"error": None, "steps": [], "failovers": 0, "server_before": None}
    vec = None
    try:
        vec = VectorClient(
            args.envs,
            endpoint=args.endpoint,
            prefix=args.prefix,
            zenoh_mode="client",
            timeout=3.0,
            failover=True,
            seed=args.seed,
            autoreset=True,
            max_agents=5,
        )
        result["server_before"] = vec.server_id
        resets = vec.reset()
        result["reset"] = [_digest(r["obs"]) for r in resets]
        t = 0
        for n in range(args.steps):
            if n == args.pause_at:
                _write_json(args.paused_file, {"server_id": vec.server_id, "step": n})
                deadline = time.monotonic() + args.wait
                while not os.path.exists(args.go_file):
                    if time.monotonic() > deadline:
                        raise TimeoutError(f"no {args.go_file} within {args.wait} s")
                    time.sleep(0.01)
            res = vec.step(_actions(t, vec.num_envs, vec.n_ext))
            failover = bool(res.get("failover", False))
            t = 0 if failover else t + 1
            result["steps"].append(
                {
                    "n": n,
                    "server": vec.server_id,
                    "failover": failover,
                    "reward": np.asarray(res["reward"]).tolist(),
                    "terminated": np.asarray(res["terminated"]).tolist(),
                    "truncated": np.asarray(res["truncated"]).tolist(),
                    "envs": [
                        [int(e), int(s)] for e, s in zip(res["episode"], res["step"], strict=True)
                    ],
                    "obs": _digest(res["obs"]),
                    "resets": _reset_digests(res, vec.num_envs),
                }
            )
        result["failovers"] = vec.failovers
        result["server_after"] = vec.server_id
    except BaseException as e:  # noqa: BLE001 - reported in the JSON result
        result["error"] = f"{type(e).__name__}: {e}\n{traceback.format_exc()}"
    finally:
        if vec is not None:
            try:
                vec.close()
            except Exception as e:  # noqa: BLE001
                result["error"] = result["error"] or f"close: {type(e).__name__}: {e}"
        _write_json(args.out, result)
    return 1 if result["error"] else 0


if __name__ == "__main__":
    sys.exit(main())
