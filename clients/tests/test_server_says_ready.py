"""``sim-server serve`` says, once it serves, in one line on stderr: its id, key prefix,
endpoints and pools (RUST_LOG unset: the default a person starting it meets)."""

from __future__ import annotations

import os
import subprocess
import time

import pytest
from conftest import free_port, sim_server_binary


def test_serve_prints_one_line_naming_id_endpoints_and_pools(tmp_path):
    binary = sim_server_binary()
    if binary is None:
        pytest.skip("sim-server binary not found: set SHAREDSPACE_SIM_SERVER or build it")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    log = tmp_path / "stderr"
    with log.open("w") as err:
        proc = subprocess.Popen(
            [
                str(binary),
                "serve",
                "--cfg",
                f'zenoh/listen/endpoints:["{endpoint}"]',
                "--cfg",
                "server_id:ready-probe",
                "--cfg",
                "prefix:readyprobe",
            ],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env=env,
        )
    try:
        deadline = time.monotonic() + 20
        while "serving" not in log.read_text() and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.05)
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    lines = [ln for ln in log.read_text().splitlines() if "serving" in ln]
    assert len(lines) == 1, log.read_text()
    line = lines[0]
    assert "\x1b[" not in line  # no colour codes in a log file
    for needle in ("sharedspace server serving", "server_id=ready-probe", endpoint, "hbs-paper"):
        assert needle in line, line
