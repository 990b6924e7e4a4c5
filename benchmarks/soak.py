"""Soak test: many trainers sharing one server for a long time (`make soak`, not in `make test`).

One release ``sim-server serve`` (started here on a free loopback port, multicast scouting off)
and ``--trainers`` trainer processes, each with ``--envs`` envs stepped by ``BatchStep`` with
random actions, for ``--minutes``. Churn, as real trainers make it:

- each trainer, about every ``--churn-s`` seconds, either closes all its envs and creates new ones
  or resets a random half of them;
- every ``--kill-every-s`` seconds one trainer is killed with SIGKILL (the injected failure: its
  envs must be reaped, server load must come back) and a fresh one takes its place.

Every second each trainer writes its env-steps and batch round-trip latencies; the server's RSS
(``/proc/{pid}/status``) and load (``ServerInfo.load``) are sampled every ``--sample-s`` seconds.
The report: env-steps/s, p50/p99 step latency and RSS per period, the RSS growth after warm-up
(the first ``--warmup-min`` minutes), the RSS slope over the last ``--slope-min`` minutes
(least squares, MiB/h), the errors seen by trainers (SIGKILLed trainers excepted), whether the
load came back to the live trainers' envs after each kill, and the server's own tables
(``ServerInfo.tables``) and allocator figures (``ServerInfo.allocator``): sampled with the RSS,
and at the end compared with their sizes before the first trainer came (the pools of reusable
step buffers are bounded, not emptied, and left out of that comparison).
PASS: no errors, load 0 at the end, every table back to its idle size, the RSS growth at most
``--max-growth`` (5 %) from the median of the first ``--heap-window-min`` (10) minutes after
warm-up to the median of the last (the highest single sample is reported, not judged: it
follows how many envs are live at that instant), and a flat live heap: what live allocations hold
(``ServerInfo.allocator.in_use``) grows by at most ``--max-heap-growth`` (1 %) from the first
``--heap-window-min`` (10) minutes after warm-up to the last (medians of the samples: the heap
follows how many envs are live at each sample, so single samples and short-window slopes swing).
The RSS slope and the live heap's slope are reported, not judged: over 2 h the RSS slope swings
by about 0.9 MiB/h between half-hours, and the heap's slope over the last hour follows the
workload's drift (docs/BENCHMARKS.md section 6), so a bound of 0.1 MiB/h on either would need a
~10-hour run to decide.
It prints a markdown table for docs/BENCHMARKS.md and writes everything to ``--out`` (JSON).

Usage: python benchmarks/soak.py [--minutes 10] [--trainers 8] [--envs 64]
       [--server target/release/sim-server] [--out out/soak/soak.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "clients" / "src"))

from client_roundtrip import free_port  # noqa: E402 - benchmarks/, beside this script


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (``/proc/{pid}/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def sim_server_pid(pid: int, binary: str) -> int:
    """The process of ``binary`` at or below ``pid`` (a ``--server-wrap`` runs it as a child)."""
    comm = Path(binary).name[:15]  # the kernel keeps 15 bytes of a process name
    todo = [pid]
    while todo:
        p = todo.pop(0)
        try:
            if Path(f"/proc/{p}/comm").read_text().strip() == comm:
                return p
            children = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except FileNotFoundError:
            continue
        todo += [int(c) for c in children]
    raise RuntimeError(f"no {comm} process under pid {pid}")


def window_medians(
    points: list[tuple[float, float]], start_s: float, end_s: float, window_s: float
) -> tuple[float, float]:
    """Medians of ``points`` (seconds, value) in ``[start_s, start_s + window_s)`` and in
    ``[end_s - window_s, end_s]``; NaN for an empty window."""
    first = [v for t, v in points if start_s <= t < start_s + window_s]
    last = [v for t, v in points if end_s - window_s <= t <= end_s]
    return (
        float(np.median(first)) if first else float("nan"),
        float(np.median(last)) if last else float("nan"),
    )


def window_growth(
    points: list[tuple[float, float]], start_s: float, end_s: float, window_s: float
) -> float:
    """Relative change from the first window's median to the last's
    (:func:`window_medians`); NaN (which no bound passes) when a window is empty."""
    first, last = window_medians(points, start_s, end_s, window_s)
    return last / first - 1.0


def slope_per_h(points: list[tuple[float, float]]) -> float:
    """Least-squares slope of (seconds, MiB) points, in MiB/h; NaN under three points."""
    if len(points) < 3:
        return float("nan")
    return (
        float(np.polyfit([t for t, _ in points], [v for _, v in points], 1)[0]) * 3600
    )


def tables_off(idle: dict, now: dict) -> dict[str, list[int]]:
    """Tables of ``now`` (a ``ServerInfo``) not at their size in ``idle``, as ``[idle, now]``;
    the bounded pools of reusable buffers (``pooled_*``) are left out."""
    a, b = idle.get("tables", {}), now.get("tables", {})
    return {
        k: [a.get(k, 0), b.get(k, 0)]
        for k in sorted(set(a) | set(b))
        if not k.startswith("pooled_") and a.get(k, 0) != b.get(k, 0)
    }


# --------------------------------------------------------------------------------------------
# A trainer process


def trainer(args: argparse.Namespace) -> None:
    """Steps ``args.envs`` envs until killed or ``args.until`` (epoch seconds); one JSON line a
    second on stdout: ``{"t", "steps", "lat_ms": [...], "errors": [...], "load_ops"}``."""
    from sharedspace.client import SimClient
    from sharedspace.vector import VectorClient

    rng = random.Random(args.seed)
    np_rng = np.random.default_rng(args.seed)
    client = SimClient(args.endpoint, timeout=30.0)

    def fresh_envs(seed: int) -> VectorClient:
        vec = VectorClient(args.envs, client=client, seed=seed, autoreset=True)
        vec.reset()
        return vec

    vec = fresh_envs(args.seed)
    next_churn = time.time() + rng.uniform(0.5, 1.5) * args.churn_s
    tick = time.time() + 1.0
    steps, lat, errors, ops = 0, [], [], {"recreate": 0, "reset": 0}
    while time.time() < args.until:
        try:
            actions = np_rng.uniform(-1, 1, (args.envs, 1, 2)).astype(np.float32)
            t0 = time.perf_counter()
            vec.step(actions)
            lat.append(round((time.perf_counter() - t0) * 1e3, 3))
            steps += args.envs
            if time.time() >= next_churn:
                if rng.random() < 0.5:
                    vec.close()
                    vec = fresh_envs(rng.randrange(1 << 30))
                    ops["recreate"] += 1
                else:
                    vec.reset(env_index=rng.sample(range(args.envs), args.envs // 2))
                    ops["reset"] += 1
                next_churn = time.time() + rng.uniform(0.5, 1.5) * args.churn_s
        except Exception as exc:  # noqa: BLE001 - every error is reported, then we go on
            errors.append(f"{type(exc).__name__}: {exc}")
            try:
                vec = fresh_envs(rng.randrange(1 << 30))
            except Exception as exc2:  # noqa: BLE001
                errors.append(f"recreate: {type(exc2).__name__}: {exc2}")
                time.sleep(1.0)
        if time.time() >= tick:
            line = {
                "t": time.time(),
                "steps": steps,
                "lat_ms": lat,
                "errors": errors,
                "ops": ops,
            }
            print(json.dumps(line), flush=True)
            steps, lat, errors, ops = 0, [], [], {"recreate": 0, "reset": 0}
            tick += 1.0
    vec.close()
    client.shutdown()


# --------------------------------------------------------------------------------------------
# The driver


class Trainer:
    def __init__(
        self, name: str, endpoint: str, envs: int, seed: int, until: float, log: Path
    ):
        self.name, self.log_path = name, log
        self.log = open(log, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--trainer",
                "--endpoint",
                endpoint,
                "--envs",
                str(envs),
                "--seed",
                str(seed),
                "--until",
                str(until),
            ],
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )
        self.killed = False

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        self.killed = True

    def stop(self, timeout: float) -> None:
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()

    def records(self) -> list[dict]:
        out = []
        for line in self.log_path.read_text().splitlines():
            if line.startswith("{"):
                out.append(json.loads(line))
        return out

    def stray_output(self) -> list[str]:
        return [
            line
            for line in self.log_path.read_text().splitlines()
            if line.strip() and not line.startswith("{")
        ]


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    numbers = [  # flag, type, default, help
        ("--minutes", float, 10.0, "soak duration (hours: 60 * h)"),
        ("--trainers", int, 8, "trainer processes at any time"),
        ("--envs", int, 64, "envs per trainer"),
        ("--churn-s", float, 10.0, "mean seconds between churn ops"),
        ("--kill-every-s", float, 60.0, "seconds between SIGKILLs"),
        ("--sample-s", float, 5.0, "seconds between RSS samples"),
        ("--period-s", float, 60.0, "report period, s"),
        ("--slope-min", float, 60.0, "RSS slope over the last this many minutes"),
        (
            "--max-growth",
            float,
            0.05,
            "PASS bound on the RSS growth after warm-up (fraction, window medians)",
        ),
        (
            "--max-heap-growth",
            float,
            0.01,
            "PASS bound on the live heap's growth after warm-up (fraction, window medians)",
        ),
        (
            "--heap-window-min",
            float,
            10.0,
            "minutes of each window the RSS and heap growths compare",
        ),
        ("--warmup-min", float, 2.0, "RSS baseline after this"),
    ]
    for flag, kind, default, text in numbers:
        ap.add_argument(flag, type=kind, default=default, help=text)
    ap.add_argument("--server", default=str(ROOT / "target" / "release" / "sim-server"))
    ap.add_argument(
        "--server-wrap",
        default="",
        help="command that runs the server, e.g. 'heaptrack -o out/soak/heap' (a heap profile)",
    )
    ap.add_argument("--out", default=str(ROOT / "out" / "soak" / "soak.json"))
    ap.add_argument("--trainer", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", default="", help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--until", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.trainer:
        trainer(args)
        return 0

    from sharedspace.client import SimClient
    from sharedspace.wire.errors import NoServer

    out = Path(args.out)
    logs = out.parent / "trainers"
    logs.mkdir(parents=True, exist_ok=True)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    server = subprocess.Popen(
        [
            *args.server_wrap.split(),
            args.server,
            "serve",
            "--cfg",
            f'zenoh/listen/endpoints:["{endpoint}"]',
            "--cfg",
            "zenoh/scouting/multicast/enabled:false",
            "--cfg",
            "server_id:soak",
        ],
        stdout=open(out.parent / "server.log", "w"),  # noqa: SIM115
        stderr=subprocess.STDOUT,
        env={**os.environ, "RUST_LOG": os.environ.get("RUST_LOG", "warn")},
    )
    observer = SimClient(endpoint, timeout=10.0)
    up_by = time.time() + 120  # a --server-wrap (a heap profiler) may start it slowly
    while True:
        try:
            observer.pick_server()
            break
        except NoServer:
            if time.time() > up_by:
                raise
            time.sleep(1.0)
    server_pid = sim_server_pid(server.pid, args.server)
    idle_info = observer.info("soak")
    start = time.time()
    until = start + args.minutes * 60
    trainers: list[Trainer] = []
    seed = 0

    def spawn() -> Trainer:
        nonlocal seed
        seed += 1
        t = Trainer(
            f"t{seed}", endpoint, args.envs, seed * 1000, until, logs / f"t{seed}.jsonl"
        )
        trainers.append(t)
        return t

    live = [spawn() for _ in range(args.trainers)]
    samples, kills = [], []
    next_kill = start + args.kill_every_s
    next_sample = start
    while time.time() < until:
        now = time.time()
        if now >= next_sample:
            info = observer.info("soak")
            samples.append(
                {
                    "t": now - start,
                    "rss_mib": rss_mib(server_pid),
                    "cpu_s": cpu_s(server_pid),
                    "load": info["load"],
                    "tables": info.get("tables", {}),
                    "allocator": info.get("allocator", {}),
                }
            )
            next_sample += args.sample_s
        if now >= next_kill and now + 15 < until:
            victim = random.Random(int(now)).choice(live)
            victim.kill()
            live.remove(victim)
            live.append(spawn())
            kills.append({"t": now - start, "trainer": victim.name})
            next_kill += args.kill_every_s
        time.sleep(0.2)
    for t in trainers:
        t.stop(timeout=60)
    final_info = observer.info("soak")
    # Trainers that were SIGKILLed are reaped after their grace: wait for the tables to settle.
    settle_by = time.time() + 30
    while tables_off(idle_info, final_info) and time.time() < settle_by:
        time.sleep(1.0)
        final_info = observer.info("soak")
    final_load = final_info["load"]
    rss_end = rss_mib(server_pid)
    observer.shutdown()
    os.kill(server_pid, signal.SIGTERM)  # the server itself, not a --server-wrap
    server.wait(timeout=30)

    # ---- report
    per: dict[int, dict] = {}
    errors = []
    for t in trainers:
        for r in t.records():
            p = int((r["t"] - start) // args.period_s)
            acc = per.setdefault(p, {"steps": 0, "lat": [], "recreate": 0, "reset": 0})
            acc["steps"] += r["steps"]
            acc["lat"] += r["lat_ms"]
            acc["recreate"] += r["ops"]["recreate"]
            acc["reset"] += r["ops"]["reset"]
            errors += [f"{t.name}: {e}" for e in r["errors"]]
        if not t.killed:
            errors += [f"{t.name} (output): {line}" for line in t.stray_output()]
    periods = []
    for p in sorted(per):
        acc = per[p]
        span = min(args.period_s, args.minutes * 60 - p * args.period_s)
        if span <= 0:
            continue  # the trainers' last lines, written as the soak ended
        inside = [
            x for x in samples if p * args.period_s <= x["t"] < (p + 1) * args.period_s
        ]
        rss = [x["rss_mib"] for x in inside]
        cpu = (
            inside[-1]["cpu_s"] - inside[0]["cpu_s"]
            if len(inside) > 1
            else float("nan")
        )
        cpu_span = inside[-1]["t"] - inside[0]["t"] if len(inside) > 1 else float("nan")
        lat = np.array(acc["lat"]) if acc["lat"] else np.array([np.nan])
        periods.append(
            {
                "period": p,
                "env_steps_per_s": acc["steps"] / span,
                "p50_ms": float(np.percentile(lat, 50)),
                "p99_ms": float(np.percentile(lat, 99)),
                "max_ms": float(lat.max()),
                "rss_mib_max": max(rss) if rss else float("nan"),
                # Server CPU per 1 000 env-steps: flat if the server does not slow down, whatever
                # share of the machine it gets.
                "server_cpu_ms_per_1k": 1e6 * cpu / (acc["steps"] / span * cpu_span)
                if acc["steps"]
                else float("nan"),
                "recreates": acc["recreate"],
                "resets": acc["reset"],
            }
        )
    warm = [s["rss_mib"] for s in samples if s["t"] >= args.warmup_min * 60]
    baseline = warm[0] if warm else float("nan")
    peak_growth = (
        (max(warm) - baseline) / baseline if warm else float("nan")
    )  # reported
    # The criterion: median RSS of the last window against the median of the first window
    # after warm-up (single highest samples follow the live envs of the moment).
    rss_first, rss_last = window_medians(
        [(s["t"], s["rss_mib"]) for s in samples],
        args.warmup_min * 60,
        args.minutes * 60,
        args.heap_window_min * 60,
    )
    growth = rss_last / rss_first - 1.0
    slope_from = max(args.warmup_min, args.minutes - args.slope_min) * 60
    tail = [(s["t"], s["rss_mib"]) for s in samples if s["t"] >= slope_from]
    slope = slope_per_h(tail)
    mib = 1 << 20
    heap_tail = [
        (s["t"], s["allocator"]["in_use"] / mib)
        for s in samples
        if s["t"] >= slope_from and "in_use" in s["allocator"]
    ]
    heap_slope = slope_per_h(heap_tail)
    heap_growth = window_growth(
        [
            (s["t"], s["allocator"]["in_use"] / mib)
            for s in samples
            if "in_use" in s["allocator"]
        ],
        args.warmup_min * 60,
        args.minutes * 60,
        args.heap_window_min * 60,
    )
    tables_left = tables_off(idle_info, final_info)
    full = [q["env_steps_per_s"] for q in periods[:-1]] or [
        periods[-1]["env_steps_per_s"]
    ]
    report = {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "command": " ".join(sys.argv),
        "trainers": args.trainers,
        "envs": args.envs,
        "minutes": args.minutes,
        "kills": kills,
        "errors": errors,
        "final_load": final_load,
        "rss_baseline_mib": baseline,
        "rss_end_mib": rss_end,
        "rss_growth_after_warmup": growth,
        "rss_median_first_window_mib": rss_first,
        "rss_median_last_window_mib": rss_last,
        "rss_peak_growth_after_warmup": peak_growth,
        "rss_slope_mib_per_h": slope,
        "rss_slope_window_min": [slope_from / 60, args.minutes],
        "heap_slope_mib_per_h": heap_slope,
        "heap_growth_after_warmup": heap_growth,
        "tables_idle": idle_info.get("tables", {}),
        "tables_end": final_info.get("tables", {}),
        "tables_not_back": tables_left,
        "allocator_idle": idle_info.get("allocator", {}),
        "allocator_end": final_info.get("allocator", {}),
        "throughput_min_max": [min(full), max(full)],
        "periods": periods,
        "samples": samples,
    }
    out.write_text(json.dumps(report, indent=1))
    print(
        f"soak: {args.trainers} trainers x {args.envs} envs, {args.minutes} min, "
        f"{len(kills)} trainers SIGKILLed and replaced ({report['date']}, {report['machine']})"
    )
    print()
    print(
        "| from (min) | env-steps/s | p50 step (ms) | p99 step (ms) | max (ms) | server RSS (MiB) | "
        "server CPU ms / 1k env-steps | recreates | resets |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for q in periods:
        print(
            f"| {q['period'] * args.period_s / 60:.1f} | {q['env_steps_per_s']:,.0f} | "
            f"{q['p50_ms']:.2f} | {q['p99_ms']:.2f} | {q['max_ms']:.1f} | "
            f"{q['rss_mib_max']:.1f} | {q['server_cpu_ms_per_1k']:.1f} | {q['recreates']} | "
            f"{q['resets']} |"
        )
    print()
    print(
        f"RSS, median of the first {args.heap_window_min:.0f} min after warm-up "
        f"({args.warmup_min} min) -> of the last {args.heap_window_min:.0f} min: "
        f"{rss_first:.1f} -> {rss_last:.1f} MiB, growth {growth * 100:+.2f} % (the criterion); "
        f"highest sample {max(warm) if warm else float('nan'):.1f} MiB, "
        f"{peak_growth * 100:+.1f} % over the first (reported); "
        f"load at the end {final_load} (every trainer closed); errors: {len(errors)}"
    )
    for e in errors[:20]:
        print("  ", e)
    alloc = [
        s["allocator"]
        for s in samples
        if s["t"] >= args.warmup_min * 60 and s["allocator"]
    ]
    if alloc:
        print(
            "allocator (MiB, after warm-up -> last sample): in use "
            f"{alloc[0]['in_use'] / mib:.1f} -> {alloc[-1]['in_use'] / mib:.1f}, "
            f"free but retained {alloc[0]['free_retained'] / mib:.1f} -> "
            f"{alloc[-1]['free_retained'] / mib:.1f}"
        )
    print(
        f"over minutes {slope_from / 60:.0f}-{args.minutes:.0f}: RSS slope {slope:+.3f} MiB/h "
        f"(reported), live heap slope {heap_slope:+.3f} MiB/h (reported)"
    )
    print(
        f"live heap, median of the first {args.heap_window_min:.0f} min after warm-up -> of the "
        f"last {args.heap_window_min:.0f} min: growth {heap_growth * 100:+.2f} % "
        f"(bound {args.max_heap_growth * 100:.0f} %)"
    )
    print(f"server tables at the end: {final_info.get('tables', {})}")
    print(f"tables not back to their idle size: {tables_left or 'none'}")
    # No allocator figures (a build that cannot ask its allocator): the heap cannot be judged.
    heap_flat = heap_growth <= args.max_heap_growth
    memory_ok = growth <= args.max_growth and heap_flat
    print(
        f"criterion: median RSS growth {growth * 100:+.2f} % (bound "
        f"{args.max_growth * 100:.0f} %), "
        f"live heap {'flat' if heap_flat else 'NOT flat'}"
    )
    ok = not errors and final_load == 0 and not tables_left and memory_ok
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
