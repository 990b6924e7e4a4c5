"""A learner process that returns from ``main`` exits, even with zenoh sessions left open.

zenoh-python runs Python callbacks on non-daemon threads that live until their session closes,
and the interpreter joins those threads before ``atexit`` handlers run: without the shutdown
hook in ``sharedspace.transport`` such a process hangs forever after its last line (this hung
a whole CI run after every test had passed).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from conftest import REPO_ROOT

EXIT_TIMEOUT_S = 30.0


def run_script(body: str) -> subprocess.CompletedProcess:
    script = textwrap.dedent(body)
    try:
        return subprocess.run(
            [sys.executable, "-c", script],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            timeout=EXIT_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"the process did not exit within {EXIT_TIMEOUT_S:g} s; stdout: {e.stdout!r}")


def test_exit_with_an_unclosed_transport_and_subscriber():
    done = run_script(
        """
        from sharedspace.transport import Transport
        t = Transport(endpoint="tcp/127.0.0.1:9", listen=["tcp/127.0.0.1:0"], timeout=0.5)
        seen = []
        sub = t.declare_subscriber("sstest/exit/**", seen.append)
        assert t.is_alive("nobody") and t.alive_servers() == set()
        kept = (t, sub)
        print("left open")
        """
    )
    assert done.returncode == 0, done.stderr
    assert "left open" in done.stdout


def test_exit_with_an_unclosed_client_and_observer(sim_server):
    done = run_script(
        f"""
        from sharedspace.client import SimClient
        from sharedspace.observer import Observer
        client = SimClient({sim_server.endpoint!r}, {sim_server.prefix!r}, timeout=5.0)
        env = client.create(split="test", seed=3)["env_ids"][0]
        client.reset(env)
        observer = Observer(transport=client.transport, env_id=env)
        client.step(env, [[0.5, 0.0]])
        kept = (client, env, observer)
        print("left open")
        """
    )
    assert done.returncode == 0, done.stderr
    assert "left open" in done.stdout
