"""The live browser viewer (viewer/, docs/VIEWER.md): a zenoh router with the remote-api plugin
beside the servers, and the page on a local HTTP port.

    python -m sharedspace.viewer --connect tcp/127.0.0.1:7447      # or: make view

The page (built by ``npm run build`` in viewer/) joins the zenoh network through the router's
WebSocket with ``@eclipse-zenoh/zenoh-ts``, lists every server's open envs
(``ServerInfo.envs``) and follows one. The router is ``sim-server router`` with
``plugins/remote_api`` configured: zenoh's remote-api plugin linked into the project's binary,
so nothing else is installed. It connects to the given endpoints (a server's listener or a
router of a deployment, deploy/README.md).
"""

from __future__ import annotations

import argparse
import functools
import http.server
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import urlencode

from sharedspace.cli import run_command

from .closing import Closing
from .local_server import (
    ENDPOINT_VAR,
    PREFIX_VAR,
    die_with_parent,
    free_port,
    sim_server_binary,
    stop_process,
    wait_port,
)

__all__ = ["VIEWER_DIST", "Viewer"]

REPO_ROOT = Path(__file__).resolve().parents[3]
#: The built page: a checkout's (``npm ci && npm run build`` in viewer/), else the copy that
#: ``make wheel`` puts in the installed package (``sharedspace/viewer_page``).
VIEWER_DIST = next(
    (
        d
        for d in (REPO_ROOT / "viewer" / "dist", Path(__file__).resolve().parent / "viewer_page")
        if (d / "index.html").is_file()
    ),
    REPO_ROOT / "viewer" / "dist",
)


class _Page(http.server.SimpleHTTPRequestHandler):
    """The page's files, and ``viewer-config.json``: the WebSocket and prefix this viewer chose
    (the page reads it, so its root URL needs no query)."""

    def __init__(self, *args, config: bytes, **kwargs):
        self._config = config
        super().__init__(*args, **kwargs)

    def do_GET(self):  # noqa: N802 - the base class's name
        if self.path.split("?", 1)[0] == "/viewer-config.json":
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(self._config)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(self._config)
            return
        super().do_GET()

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass


class Viewer(Closing):
    """A router with the remote-api plugin connected to ``connect`` and an HTTP server of the
    page; a context manager (both stop on exit).

    Args:
        connect: zenoh endpoints of the servers or routers to watch.
        prefix: the servers' key prefix.
        http_port, ws_port: local ports of the page and of the WebSocket (0 = a free one).
        host: interface both listen on (loopback by default: the plugin has no authentication).
        dist: the built page.
        max_hz: most states / risk-graph messages per second and env that reach the page; the
            router drops the rest as they arrive from the servers (zenoh's ``downsampling``),
            so a viewer following a lockstep env that steps thousands of times a second costs
            the machine little (each message costs the browser a fraction of a millisecond).
            Events are sampled too (the page also reads outcomes from the reward terms). 0 = all.
    """

    def __init__(
        self,
        connect: str | Sequence[str],
        prefix: str = "sharedspace",
        http_port: int = 0,
        ws_port: int = 0,
        host: str = "127.0.0.1",
        dist: Path = VIEWER_DIST,
        max_hz: float = 4.0,
    ):
        if not (Path(dist) / "index.html").is_file():
            raise FileNotFoundError(
                f"{dist}/index.html is missing: build the page with `npm ci && npm run build` "
                "in viewer/ (or `make view`), or install the wheel of `make wheel` (it carries it)"
            )
        endpoints = [connect] if isinstance(connect, str) else list(connect)
        self.prefix = prefix
        self.host = host
        self.ws_port = ws_port or free_port()
        router_port = free_port()
        quoted = ",".join(f'"{e}"' for e in endpoints)
        cmd = [
            str(sim_server_binary()),
            "router",
            "--cfg",
            f'listen/endpoints:["tcp/127.0.0.1:{router_port}"]',
            "--cfg",
            f"connect/endpoints:[{quoted}]",
            "--cfg",
            f'plugins/remote_api/websocket_port:"{host}:{self.ws_port}"',
        ]
        if max_hz > 0:
            rules = ",".join(
                f'{{key_expr:"{prefix}/env/*/{topic}",freq:{float(max_hz)}}}'
                for topic in ("states", "risk_graph", "uncertainty", "events")
            )
            cmd += [
                "--cfg",
                f'downsampling:[{{id:"viewer",messages:["put"],flows:["ingress"],rules:[{rules}]}}]',
            ]
        # Its own session (a Ctrl-C in the terminal reaches the viewer, which stops it), and it
        # dies with the viewer however the viewer ends (SIGTERM, SIGKILL).
        self._router = subprocess.Popen(
            cmd,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=die_with_parent,
        )
        try:
            wait_port(self.ws_port, self._router, 20.0, "the viewer's router")
            config = json.dumps({"ws": f"ws://{host}:{self.ws_port}", "prefix": prefix}).encode()
            handler = functools.partial(_Page, directory=str(dist), config=config)
            self._http = http.server.ThreadingHTTPServer((host, http_port), handler)
        except BaseException:
            self._stop_router()
            raise
        self.http_port = self._http.server_address[1]
        self._thread = threading.Thread(target=self._http.serve_forever, daemon=True)
        self._thread.start()

    def url(self, env_id: str | None = None, edges_per_agent: int | None = None) -> str:
        """The page's address (following ``env_id`` at once when given)."""
        query = {"ws": f"ws://{self.host}:{self.ws_port}", "prefix": self.prefix}
        if env_id:
            query["env"] = env_id
        if edges_per_agent is not None:
            query["k"] = str(edges_per_agent)
        return f"http://{self.host}:{self.http_port}/index.html?{urlencode(query)}"

    def _stop_router(self) -> None:
        stop_process(self._router)

    def close(self) -> None:
        self._http.shutdown()
        self._http.server_close()
        self._stop_router()


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    named = os.environ.get(ENDPOINT_VAR, "")
    ap.add_argument(
        "--connect",
        nargs="+",
        default=[e.strip() for e in named.split(",") if e.strip()] or ["tcp/127.0.0.1:7447"],
        help="zenoh endpoints of the servers (or a router) to watch (default: "
        "$SHAREDSPACE_ENDPOINT's, else tcp/127.0.0.1:7447)",
    )
    ap.add_argument(
        "--prefix",
        default=os.environ.get(PREFIX_VAR) or "sharedspace",
        help="the servers' key prefix (default: $SHAREDSPACE_PREFIX, else sharedspace)",
    )
    ap.add_argument("--http", type=int, default=8090, help="port of the page")
    ap.add_argument("--ws", type=int, default=10000, help="port of the zenoh WebSocket")
    ap.add_argument("--host", default="127.0.0.1", help="interface of both ports")
    ap.add_argument(
        "--max-hz", type=float, default=4.0, help="most frames per second and env (0 = all)"
    )
    args = ap.parse_args(argv)
    # SIGTERM ends the viewer like Ctrl-C: the `with` below stops the router and the page.
    signal.signal(signal.SIGTERM, _interrupt)
    with Viewer(
        args.connect, args.prefix, args.http, args.ws, args.host, max_hz=args.max_hz
    ) as viewer:
        print(f"viewer: open {viewer.url()}  (Ctrl-C stops)", flush=True)
        try:
            threading.Event().wait()
        except KeyboardInterrupt:
            pass


if __name__ == "__main__":
    sys.exit(run_command(main))
