"""The live browser viewer, in Debian's Chromium (headless, through chromium-driver), against a
real server: the page joins zenoh through the router's remote-api WebSocket, lists the open env,
follows it step by step and across a reset, draws the right number of agents and risk edges,
pauses, shows a clicked agent's u and psi, and moves on to the next env when its env closes.

``make test`` installs Chromium and builds the page and sets SHAREDSPACE_REQUIRE_BROWSER=1, so
there a missing browser fails the test instead of skipping it. The screenshot is written to the
test's temporary folder, and also to ``$SHAREDSPACE_VIEWER_SCREENSHOT`` when set (that is how
docs/figures/viewer.png was made).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import unique_prefix

from sharedspace.client import SimClient
from sharedspace.local_server import free_port
from sharedspace.observer import Observer
from sharedspace.viewer import VIEWER_DIST, Viewer

CHROMIUM = shutil.which("chromium")
CHROMEDRIVER = shutil.which("chromedriver")
ATTRS = ("env", "episode", "step", "agents", "edges", "edges-drawn", "frames", "outcome")


def _require_browser():
    missing = [
        what
        for what, ok in (
            ("chromium", CHROMIUM),
            ("chromedriver", CHROMEDRIVER),
            ("viewer/dist (npm run build)", (VIEWER_DIST / "index.html").is_file()),
        )
        if not ok
    ]
    try:
        import selenium  # noqa: F401
    except ImportError:
        missing.append("selenium")
    if missing:
        if os.environ.get("SHAREDSPACE_REQUIRE_BROWSER") == "1":
            pytest.fail(f"the browser test needs {', '.join(missing)} (make test installs them)")
        pytest.skip(f"missing {', '.join(missing)}")


@pytest.fixture
def browser():
    _require_browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1280,760"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(30)
    driver.set_script_timeout(10)
    yield driver
    driver.quit()


def _shown(driver) -> dict[str, str]:
    """The page's episode table's data attributes, read in one script (one consistent frame)."""
    data = driver.execute_script("return {...document.getElementById('episode').dataset};")
    names = {k: k.replace("-d", "D") for k in ATTRS}  # data-edges-drawn -> dataset.edgesDrawn
    return {k: str(data.get(names[k], "")) for k in ATTRS}


def _wait(driver, pred, timeout: float, what: str) -> dict[str, str]:
    deadline = time.monotonic() + timeout
    shown = _shown(driver)
    while time.monotonic() < deadline:
        shown = _shown(driver)
        if pred(shown):
            return shown
        time.sleep(0.1)
    raise AssertionError(f"viewer did not show {what} within {timeout} s; it shows {shown}")


class Stepper:
    """Steps one lockstep env with zero actions every ``period`` seconds on a thread (slower
    than the viewer's default 4 frames per second, so that the page gets every state)."""

    def __init__(self, client: SimClient, env_id: str, period: float = 0.3):
        self.client, self.env_id, self.period = client, env_id, period
        self.running = threading.Event()
        self.stop = threading.Event()
        self.last: dict | None = None
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            if self.running.is_set():
                with self.lock:
                    self.last = self.client.step(self.env_id, np.zeros((1, 2), np.float32))
            time.sleep(self.period)

    def close(self):
        self.stop.set()
        self.thread.join(timeout=10)


def _strongest_per_observer(src, dst, a, present, k=2):
    chosen = 0
    for s in set(int(x) for x in src):
        if s not in present:
            continue
        n = sum(1 for i in range(len(src)) if src[i] == s and int(dst[i]) in present)
        chosen += min(k, n)
    return chosen


def test_the_viewer_follows_a_live_env_with_its_agents_and_risk_edges(
    server_factory, browser, tmp_path
):
    server = server_factory(unique_prefix(), "view0")
    client = SimClient(server.endpoint, server.prefix, timeout=5.0)
    env_id = client.create(1, max_agents=8, autoreset=True)["env_ids"][0]
    client.reset(env_id, seed=3)
    stepper = Stepper(client, env_id)
    watched: dict[tuple[str, int, int], dict] = {}

    def keep(msg):
        watched[(msg["topic"], int(msg["episode"]), int(msg["step"]))] = msg

    try:
        with (
            Viewer(server.endpoint, server.prefix) as viewer,
            Observer(
                server.endpoint,
                server.prefix,
                env_id=env_id,
                topics=("states", "risk_graph"),
                callback=keep,
            ),
        ):
            # The root URL, no query: the page learns the WebSocket (a free port, not the
            # default 10000) and the prefix from the viewer that serves it; no env given: it
            # picks the open one.
            browser.get(f"http://127.0.0.1:{viewer.http_port}/index.html")
            _wait(browser, lambda s: s["env"] == env_id, 30, f"env {env_id}")
            assert env_id in browser.find_element("id", "envs").text
            assert (
                f"ws://127.0.0.1:{viewer.ws_port}" in browser.find_element("id", "connection").text
            )

            # It follows the env step by step.
            stepper.running.set()
            first = _wait(browser, lambda s: s["step"] not in ("", "0"), 20, "a step")
            later = _wait(
                browser, lambda s: int(s["frames"]) >= int(first["frames"]) + 5, 20, "5 frames"
            )
            assert (int(later["episode"]), int(later["step"])) > (
                int(first["episode"]),
                int(first["step"]),
            )

            # Stopped, it shows the last state with every agent and edge of that state.
            stepper.running.clear()
            time.sleep(stepper.period * 2)
            with stepper.lock:
                last = stepper.last
            ep, st = int(last["episode"]), int(last["step"])
            # an autoreset may already have started the next episode's step 0
            shown = _wait(
                browser,
                lambda s: (s["episode"], s["step"]) in ((str(ep), str(st)), (str(ep + 1), "0")),
                10,
                f"episode {ep} step {st}",
            )
            key_ep, key_st = int(shown["episode"]), int(shown["step"])
            states = watched[("states", key_ep, key_st)]
            graph = watched[("risk_graph", key_ep, key_st)]
            present = {int(i) for i in states["ids"]}
            assert int(shown["agents"]) == len(present) > 1
            live_edges = sum(
                1
                for s, d in zip(graph["src"], graph["dst"], strict=True)
                if int(s) in present and int(d) in present
            )
            assert int(shown["edges"]) == live_edges
            assert int(shown["edges-drawn"]) == _strongest_per_observer(
                graph["src"], graph["dst"], graph["a"], present
            )

            # A click on the controlled vehicle selects it: its u and psi are shown.
            x, y = browser.execute_script(
                """
                const v = window.viewer, a = v.frame.agents.find((a) => a.external);
                const c = document.getElementById('scene'), r = c.getBoundingClientRect();
                const px = c.width / 2 + (a.x - v.view.cx) * v.view.scale;
                const py = c.height / 2 - (a.y - v.view.cy) * v.view.scale;
                return [px / devicePixelRatio - r.width / 2, py / devicePixelRatio - r.height / 2];
                """
            )
            from selenium.webdriver.common.action_chains import ActionChains

            canvas = browser.find_element("id", "scene")
            ActionChains(browser).move_to_element_with_offset(
                canvas, int(x), int(y)
            ).click().perform()
            deadline = time.monotonic() + 5
            selected = ""
            while time.monotonic() < deadline and "vehicle" not in selected:
                selected = browser.find_element("id", "selected").text
                time.sleep(0.05)
            assert "vehicle" in selected and "(learner)" in selected, selected
            assert "max u" in selected and "max psi" in selected

            # Pause holds the picture while the env goes on; resume follows it again.
            browser.find_element("id", "pause").click()
            held = _shown(browser)
            stepper.running.set()
            time.sleep(1.5)
            assert _shown(browser)["frames"] == held["frames"]
            browser.find_element("id", "pause").click()
            _wait(browser, lambda s: int(s["frames"]) > int(held["frames"]), 10, "new frames")

            # It follows the env into its next episode.
            stepper.running.clear()
            time.sleep(stepper.period * 2)
            before = int(_shown(browser)["episode"])
            client.reset(env_id, seed=5)
            stepper.running.set()
            _wait(
                browser,
                lambda s: int(s["episode"]) > before and int(s["step"]) >= 2,
                20,
                "the next episode",
            )
            rewards = browser.find_element("id", "rewards").text
            assert "progress" in rewards and "return so far" in rewards, rewards

            shot = tmp_path / "viewer.png"
            assert browser.save_screenshot(str(shot))
            assert shot.stat().st_size > 10_000
            if os.environ.get("SHAREDSPACE_VIEWER_SCREENSHOT"):
                shutil.copy(shot, Path(os.environ["SHAREDSPACE_VIEWER_SCREENSHOT"]))
            # Its env closed (a trainer restarting), the page follows the next open env: one of
            # hbs-general, whose other cars are reactive (the pool's default vehicle model).
            stepper.close()
            client.close(env_id)
            env2 = client.create(1, pool="hbs-general", max_agents=8, autoreset=True)["env_ids"][0]
            client.reset(env2, seed=7)
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and _shown(browser)["env"] != env2:
                client.step(env2, np.zeros((1, 2), np.float32))
                time.sleep(0.3)
            assert _shown(browser)["env"] == env2
            # The reactive cars arrive as agents marked `reactive` (StatesMsg.reactive, read by
            # wire.js's generic per-agent fields) and are painted amber, not replay grey.
            script = """
                const v = window.viewer, c = document.getElementById('scene');
                if (!v.frame || v.frame.envId !== arguments[0]) return null;
                const ctx = c.getContext('2d');
                return v.frame.agents
                  .filter((a) => a.kind === 'vehicle' && !a.external && a.reactive === 1)
                  .map((a) => [
                    Math.round(c.width / 2 + (a.x - v.view.cx) * v.view.scale),
                    Math.round(c.height / 2 - (a.y - v.view.cy) * v.view.scale),
                  ])  // the camera follows the ego: only the cars in the picture
                  .filter(([px, py]) => px >= 0 && py >= 0 && px < c.width && py < c.height)
                  .map(([px, py]) => Array.from(ctx.getImageData(px, py, 1, 1).data));
                """
            centres = None
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not centres:
                client.step(env2, np.zeros((1, 2), np.float32))
                time.sleep(0.3)
                centres = browser.execute_script(script, env2)
            assert centres, "no reactive car in the picture of an hbs-general env"
            amber = [
                rgb
                for rgb in centres
                if abs(rgb[0] - 0xE0) + abs(rgb[1] - 0xA0) + abs(rgb[2] - 0x30) < 40
            ]
            assert amber, f"no reactive car's centre is amber: {centres}"

            severe = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
            assert not [e for e in severe if "favicon" not in e["message"]], severe
    finally:
        stepper.close()
        client.shutdown()


def test_the_viewer_names_an_unreachable_websocket(browser):
    dist = VIEWER_DIST
    with Viewer("tcp/127.0.0.1:9", "nobody", dist=dist) as viewer:
        # the page, pointed at a port where no WebSocket listens
        browser.get(f"http://127.0.0.1:{viewer.http_port}/index.html?ws=ws://127.0.0.1:9")
        deadline = time.monotonic() + 20
        text = ""
        while time.monotonic() < deadline:
            text = browser.find_element("id", "connection").text
            if "cannot reach" in text:
                break
            time.sleep(0.1)
        assert "cannot reach ws://127.0.0.1:9" in text


def _require_page():
    if not (VIEWER_DIST / "index.html").is_file():
        if os.environ.get("SHAREDSPACE_REQUIRE_BROWSER") == "1":
            pytest.fail("viewer/dist is missing (make test builds it)")
        pytest.skip("viewer/dist is missing (npm ci && npm run build in viewer/)")


def test_the_viewer_serves_the_websocket_and_prefix_it_chose():
    _require_page()
    with Viewer("tcp/127.0.0.1:9", "somewhere", max_hz=0) as viewer:
        url = f"http://127.0.0.1:{viewer.http_port}/viewer-config.json"
        with urllib.request.urlopen(url, timeout=10) as reply:
            served = json.loads(reply.read())
    assert served == {"ws": f"ws://127.0.0.1:{viewer.ws_port}", "prefix": "somewhere"}


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(c) for c in path.read_text().split()] if path.exists() else []


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has ended


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_the_viewers_router_dies_with_it(sig):
    _require_page()
    if not Path("/proc/self/task").exists():
        pytest.skip("needs /proc")
    viewer = subprocess.Popen(
        [sys.executable, "-m", "sharedspace.viewer", "--connect", "tcp/127.0.0.1:9"]
        + ["--http", "0", "--ws", str(free_port()), "--prefix", unique_prefix()],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert "viewer: open" in viewer.stdout.readline()  # the router and the page are up
        routers = _children(viewer.pid)
        assert routers, "the viewer started its router"
        viewer.send_signal(sig)
        viewer.wait(timeout=20)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(_alive(p) for p in routers):
            time.sleep(0.1)
        assert not any(_alive(p) for p in routers), f"router {routers} outlived the viewer"
    finally:
        if viewer.poll() is None:
            viewer.kill()


def test_the_camera_follows_the_ego_to_the_end_of_its_episode(server_factory, browser):
    """The car, driven off its route at full throttle and full turn until the horizon (a test
    scene where that hits nobody: 39 steps), ends its episode far outside the picture the
    episode opened with; the page, following it, shows it inside the canvas at the last step."""
    server = server_factory(unique_prefix(), "view1")
    client = SimClient(server.endpoint, server.prefix, timeout=5.0)
    env_id = client.create(1, max_agents=8, split="test")["env_ids"][0]
    client.reset(env_id, seed=0, scenario="hbs-car1387")
    where = """
        const v = window.viewer, c = document.getElementById('scene');
        if (!v.frame || !v.view) return null;
        const a = v.frame.agents.find((a) => a.external);
        if (!a) return null;
        return {step: v.frame.step, x: a.x, y: a.y, scale: v.view.scale, w: c.width, h: c.height,
                px: c.width / 2 + (a.x - v.view.cx) * v.view.scale,
                py: c.height / 2 - (a.y - v.view.cy) * v.view.scale};
        """
    try:
        with Viewer(server.endpoint, server.prefix) as viewer:
            browser.get(f"http://127.0.0.1:{viewer.http_port}/index.html")
            _wait(browser, lambda s: s["env"] == env_id, 30, f"env {env_id}")
            client.step(env_id, np.zeros((1, 2), np.float32))
            _wait(browser, lambda s: s["step"] == "1", 20, "step 1")
            start = browser.execute_script(where)
            done, step = False, 1
            while not done:
                reply = client.step(env_id, np.array([[1.0, 1.0]], np.float32))
                done = bool(reply["terminated"][0] or reply["truncated"][0])
                step += 1
                time.sleep(0.3)  # slower than the page's frame rate: it gets every state
            last = _wait(browser, lambda s: s["step"] == str(step), 20, f"the last step {step}")
            end = browser.execute_script(where)
            assert int(last["step"]) == end["step"] == step
            moved = np.hypot(end["x"] - start["x"], end["y"] - start["y"]) * start["scale"]
            assert moved > max(start["w"], start["h"]) / 2, (start, end)  # out of the first fit
            assert 0 <= end["px"] <= end["w"] and 0 <= end["py"] <= end["h"], end
    finally:
        client.shutdown()


def test_a_pedestrian_a_learner_drives_is_drawn_apart_and_followed(server_factory, browser):
    """An env whose learner drives a pedestrian: the page paints it purple (the simulated ones
    stay green) and keeps it at the centre of the picture."""
    server = server_factory(unique_prefix(), "view2")
    client = SimClient(server.endpoint, server.prefix, timeout=5.0)
    env_id = client.create(1, max_agents=8, split="test", external_agents=("pedestrian_0",))[
        "env_ids"
    ][0]
    client.reset(env_id, seed=0, scenario="hbs-car1387")
    script = """
        const v = window.viewer, c = document.getElementById('scene');
        if (!v.frame || !v.view) return null;
        const ctx = c.getContext('2d');
        return v.frame.agents.filter((a) => a.kind === 'pedestrian').map((a) => {
            const px = Math.round(c.width / 2 + (a.x - v.view.cx) * v.view.scale);
            const py = Math.round(c.height / 2 - (a.y - v.view.cy) * v.view.scale);
            const patch = Array.from(ctx.getImageData(px - 2, py - 2, 5, 5).data);
            const rgbs = [];  // the disc's pixels around its centre (the arrow crosses it)
            for (let i = 0; i < patch.length; i += 4) rgbs.push(patch.slice(i, i + 3));
            return {external: a.external, px: px, py: py, w: c.width, h: c.height, rgbs: rgbs};
        });
        """
    try:
        with Viewer(server.endpoint, server.prefix) as viewer:
            browser.get(f"http://127.0.0.1:{viewer.http_port}/index.html")
            _wait(browser, lambda s: s["env"] == env_id, 30, f"env {env_id}")
            peds = None
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not (peds and any(p["external"] for p in peds)):
                client.step(env_id, np.array([[1.0, 0.0]], np.float32))
                time.sleep(0.3)
                peds = browser.execute_script(script)
            assert peds, "no pedestrian drawn"
            (me,) = [p for p in peds if p["external"]]

            def near(rgb, want):
                return sum(abs(c - w) for c, w in zip(rgb, want, strict=True)) < 40

            assert any(near(rgb, (0x94, 0x67, 0xBD)) for rgb in me["rgbs"]), me  # purple
            # followed: at the canvas's centre (to the rounding of an odd height)
            assert abs(me["px"] - me["w"] / 2) <= 1 and abs(me["py"] - me["h"] / 2) <= 1, me
            for other in (p for p in peds if not p["external"]):
                inside = 0 <= other["px"] < other["w"] and 0 <= other["py"] < other["h"]
                if inside:
                    assert any(near(rgb, (0x2C, 0xA0, 0x2C)) for rgb in other["rgbs"]), other
    finally:
        client.shutdown()
