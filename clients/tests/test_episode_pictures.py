"""A played episode as pictures (sharedspace.paper.episode) against a live server."""

from __future__ import annotations

import pytest
from PIL import Image

from sharedspace.paper.drivers import make_driver
from sharedspace.paper.episode import episode_figure, record_episode, write_gif, write_mp4
from sharedspace.pettingzoo_env import SharedSpaceParallelEnv


def test_an_episode_becomes_a_gif_an_mp4_and_the_four_snapshot_figure(sim_server, tmp_path):
    env = SharedSpaceParallelEnv(
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        split="test",
        render_mode="rgb_array",
    )
    try:
        ep = record_episode(env, make_driver("pursuit_3"), "hbs-car1301")
    finally:
        env.close()
    steps = len(ep.speeds) - 1
    assert steps >= 3 and ep.outcome in ("success", "collision", "timeout")
    # A frame for (nearly) every step: the publications are subscribed before the reset.
    assert len(ep.frames) >= steps
    assert all(any(a.controlled for a in f.agents) for f in ep.frames)
    assert ep.frames[0].goals  # the controlled vehicle's goal is drawn
    gif = write_gif(ep, tmp_path / "ep.gif", size=(200, 200))
    with Image.open(gif) as img:
        assert img.n_frames == len(ep.frames) and img.size == (200, 200)
    pytest.importorskip("imageio_ffmpeg")
    mp4 = write_mp4(ep, tmp_path / "ep.mp4", size=(208, 208))
    assert mp4.stat().st_size > 1000
    fig = episode_figure(ep, tmp_path / "ep.png", [2.0] * 20, [0.0] * 20)
    with Image.open(fig) as img:
        assert img.size[0] > 1000
