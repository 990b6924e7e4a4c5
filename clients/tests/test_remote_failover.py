"""Failover: two servers, the one hosting the envs is SIGKILLed."""

from __future__ import annotations

import logging
import signal

import numpy as np
import pytest
from conftest import unique_prefix, wait_until

from sharedspace.client import SimClient
from sharedspace.transport import ServerLost
from sharedspace.vector import VectorClient


@pytest.fixture
def two_servers(server_factory):
    prefix = unique_prefix()
    a = server_factory(prefix, "fa")
    b = server_factory(prefix, "fb")
    return prefix, {"fa": a, "fb": b}


def _client(prefix, servers) -> SimClient:
    client = SimClient([s.endpoint for s in servers.values()], prefix, timeout=3.0)
    assert wait_until(lambda: len(client.servers(timeout=1.0)) == 2, 10.0)
    return client


def test_step_raises_server_lost_then_recreate(two_servers, caplog):
    prefix, servers = two_servers
    with _client(prefix, servers) as client:
        vec = VectorClient(3, client=client, seed=4, autoreset=True, max_agents=5)
        first = [r["scenario"] for r in vec.reset()]
        vec.step(np.zeros((3, 1, 2), np.float32))
        host = vec.server_id
        servers[host].kill(signal.SIGKILL)
        with pytest.raises(ServerLost, match=host) as err:
            for _ in range(50):  # the loss is seen at once, or at the latest within the timeout
                vec.step(np.zeros((3, 1, 2), np.float32))
        assert err.value.server_id == host
        with caplog.at_level(logging.WARNING, logger="sharedspace"):
            resets = vec.recreate()
        assert vec.server_id != host and vec.failovers == 1
        assert "failover #1" in caplog.text
        # same create parameters: the sequence restarts from the seed
        assert [r["scenario"] for r in resets] == first
        res = vec.step(np.zeros((3, 1, 2), np.float32))
        assert res["obs"]["features"].shape == (3, 1, 5, 11)
        vec.close()


def test_failover_true_continues_on_the_other_server(two_servers):
    torch = pytest.importorskip("torch")
    from sharedspace.torchrl_env import RemoteBatchedEnv

    prefix, servers = two_servers
    with _client(prefix, servers) as client:
        env = RemoteBatchedEnv(num_envs=2, max_agents=5, seed=1, client=client, failover=True)
        td = env.reset()
        host = env.server_id
        td["action"] = torch.zeros(2, 2)
        out, td = env.step_and_maybe_reset(td)
        servers[host].kill(signal.SIGKILL)
        td["action"] = torch.zeros(2, 2)
        out, td = env.step_and_maybe_reset(td)
        assert out["next", "truncated"].all() and out["next", "done"].all()
        assert env.failovers == 1 and env.server_id != host
        assert not td["done"].any()
        for _ in range(5):
            td["action"] = torch.zeros(2, 2)
            out, td = env.step_and_maybe_reset(td)
        assert env.failovers == 1
        env.close()
