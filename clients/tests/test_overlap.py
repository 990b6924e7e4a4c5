"""Collection overlapped with the update (sharedspace.train.overlap) against a live server: each
batch is played by the policy one update behind, exactly; the loss divides by the
log-probabilities that policy recorded; an error in the collector thread reaches the learner;
the config key turns it off."""

from __future__ import annotations

import copy

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from test_ppo import TINY as PPO_TINY  # noqa: E402

from sharedspace.train import ppo  # noqa: E402
from sharedspace.train.config import load_config  # noqa: E402
from sharedspace.train.loop import make_collector, overlaps  # noqa: E402
from sharedspace.train.overlap import OverlappedCollector  # noqa: E402
from sharedspace.train.policy import OBS_KEYS  # noqa: E402
from sharedspace.train.train import train  # noqa: E402

#: test_ppo's tiny PPO, on the test split (no carve to serve) with the risk graph
TINY = [*PPO_TINY, "network=gcn_risk", "eval_split=test"]


def _config(sim_server, tmp_path, *more: str):
    remote = [f"server_endpoint={sim_server.endpoint}", f"server_prefix={sim_server.prefix}"]
    return load_config(None, [*TINY, *remote, f"log_dir={tmp_path}", *more])


def _distribution(actor, weights, data) -> tuple[torch.Tensor, torch.Tensor]:
    """The Gaussian (before the tanh) that ``actor`` with ``weights`` gives ``data``'s
    observations."""
    probe = copy.deepcopy(actor)
    probe.load_state_dict(weights)
    with torch.no_grad():
        out = probe(data.select(*OBS_KEYS).clone())
    return out["loc"], out["scale"]


def test_each_batch_is_played_by_the_policy_one_update_behind(sim_server, tmp_path):
    """Batches 0 and 1 by the initial weights, batch k >= 2 by the weights after the update on
    batch k - 2: the recorded distributions are exactly those, and not the newest weights'
    (the lag is real, so a collector that played the learner's own actor would fail here)."""
    cfg = _config(sim_server, tmp_path, "total_frames=192", "overlap=true")
    world = ppo.make_world(cfg)
    env = world.make_env(seed=cfg.seed)
    learner = ppo.make_learner(cfg, world, env)
    collector = make_collector(cfg, env, learner, cfg.total_frames, 0)
    assert isinstance(collector, OverlappedCollector) and overlaps(cfg)
    snapshots = [copy.deepcopy(learner.actor.state_dict())]  # after 0, 1, ... updates
    counters = {"frames": 0, "updates": 0}
    batches = 0
    try:
        for k, data in enumerate(collector):
            acted = snapshots[max(k - 1, 0)]
            loc, scale = _distribution(learner.actor, acted, data)
            torch.testing.assert_close(data["loc"], loc, rtol=0, atol=1e-6)
            torch.testing.assert_close(data["scale"], scale, rtol=0, atol=1e-6)
            if k >= 2:  # the newest weights would have acted otherwise
                newest, _ = _distribution(learner.actor, snapshots[k], data)
                assert (newest - data["loc"]).abs().max() > 1e-4
            counters["frames"] += data.numel()
            learner.step(data, counters)
            collector.update_policy_weights_()
            snapshots.append(copy.deepcopy(learner.actor.state_dict()))
            batches += 1
    finally:
        collector.shutdown()
        env.close()
    assert batches == 192 // 32


def test_the_loss_divides_by_the_recorded_log_probability(sim_server, tmp_path):
    """PPO's ratio is ``exp(log pi_new(a) - recorded log-prob)``: raising every recorded
    log-probability by ``c`` scales the unclipped surrogate by ``exp(-c)``. A loss that
    recomputed the acting policy's log-probabilities from the updated actor would not move."""
    cfg = _config(sim_server, tmp_path, "total_frames=32", "clip_epsilon=0.9", "overlap=true")
    world = ppo.make_world(cfg)
    env = world.make_env(seed=cfg.seed)
    learner = ppo.make_learner(cfg, world, env)
    collector = make_collector(cfg, env, learner, cfg.total_frames, 0)
    try:
        data = next(iter(collector))
    finally:
        collector.shutdown()
        env.close()
    update = learner.update
    with torch.no_grad():
        update.gae(data)
    flat = data.reshape(-1)
    key = update.log_prob_key
    assert key in flat.keys()
    base = update.loss(flat.clone())["loss_objective"]
    shifted = flat.clone()
    shifted[key] = shifted[key] + 0.5
    moved = update.loss(shifted)["loss_objective"]
    torch.testing.assert_close(moved, base * torch.exp(torch.tensor(-0.5)), rtol=1e-4, atol=1e-6)


def test_an_error_in_the_collector_thread_reaches_the_learner():
    """The thread's exception is raised from the learner's iteration, and shutdown returns."""

    class Broken:
        def __iter__(self):
            yield {"batch": 0}
            raise RuntimeError("server lost, no survivor")

        def shutdown(self):
            self.stopped = True

    inner = Broken()
    collector = OverlappedCollector(torch.nn.Linear(2, 2), lambda behaviour: inner)
    got = []
    with pytest.raises(RuntimeError, match="no survivor"):
        for data in collector:
            got.append(data)
            collector.update_policy_weights_()
    collector.shutdown()
    assert got == [{"batch": 0}] and inner.stopped


def test_shutdown_stops_a_collector_nobody_reads():
    """A run that ends early (an error in the update, a KeyboardInterrupt) leaves no thread
    behind, even one blocked handing over a batch."""

    class Endless:
        def __iter__(self):
            while True:
                yield {"batch": 1}

        def shutdown(self):
            pass

    collector = OverlappedCollector(torch.nn.Linear(2, 2), lambda behaviour: Endless())
    for _ in collector:
        break
    collector.shutdown()
    assert not collector._thread.is_alive()


def test_overlap_off_collects_and_updates_in_turn(sim_server, tmp_path):
    """``overlap=false``: TorchRL's own collector over the learner's actor; the run trains as
    with the overlap (the same frames, iterations and updates)."""
    cfg = _config(sim_server, tmp_path, "total_frames=64", "overlap=false")
    assert not overlaps(cfg)
    out = train(cfg)
    assert out["counters"]["frames"] == 64 and out["counters"]["iterations"] == 2
    assert out["counters"]["updates"] == 2 * 2 * 2
