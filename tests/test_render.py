"""Rendering for people: map, frames, episodes, video files and the `python -m jaxsocial.render` CLI (random
actions, or a trained learner beside its companions with its predicted view)."""

import shutil
import subprocess
import sys

import imageio.v3 as iio
import jax
import numpy as np
import pytest
from conftest import TINY, TINY_ENV_ARGS, TINY_SLOTS

import jaxsocial
from jaxsocial import playback
from jaxsocial import render as cli
from jaxsocial.env import pictures, sprites
from jaxsocial.env.pictures import (
    DECODER_TITLES,
    TITLE_COLOR,
    agent_titles,
    episode_frames,
    render_frame,
    render_map,
    rollout_episode,
    save_episode,
    title_height,
    upscale,
)
from jaxsocial.env.types import BONUS, COLORS, EMPTY

LAYOUT = [
    "#############",
    "#0..........#",
    "#...........#",
    "#...........#",
    "#...........#",
    "#.....1.....#",
    "#...........#",
    "#.........#.#",
    "#...........#",
    "#...........#",
    "#.......2...#",
    "#...........#",
    "#############",
]
TILE = 12
STRIP = 3
"""Rows of the shared-cell strip at TILE pixels per cell (the last one black)."""


def fixed_params():
    return jaxsocial.make("goalcycle3", max_steps=5, agent_colors="fixed")[1]


def scene(params, **kwargs):
    # Agents 0 and 2 share (3, 3); agent 2 arrived first. Agent 1 stands on bonus tile 1 at (6, 5).
    pos = [(3, 3), (6, 5), (3, 3)]
    kwargs.setdefault("arrival", [4, 0, 2])
    return jaxsocial.state_from_layout(params, LAYOUT, pos, [0, 3, 1], **kwargs)


def cell(image, x, y, tile=TILE):
    return image[y * tile : (y + 1) * tile, x * tile : (x + 1) * tile]


def expected_cell(tile_type, direction, color, mode, tile=TILE):
    return upscale(sprites.cell_sprite(tile_type, direction, color, mode), sprites.TILE, tile)


def test_render_map_tiles_and_agents():
    params = fixed_params()
    image = render_map(scene(params), params, tile=TILE, fov=False)
    assert image.shape == (13 * TILE, 13 * TILE, 3) and image.dtype == np.uint8
    assert (cell(image, 0, 0) == COLORS["worst"]).all()  # border wall
    assert (cell(image, 10, 7) == (74, 65, 42)).all()  # clutter wall at x=10, y=7
    assert (cell(image, 1, 1) == COLORS["yellow"]).all()  # bonus tile 0, no agent
    assert (cell(image, 2, 2) == 0).all()  # empty
    # Shared cell: the earliest arrival (agent 2, purple, facing south) is drawn, and a strip along the top
    # has a segment per agent, the drawn one first: both agents are visible.
    purple, red = COLORS["purple"], COLORS["red"]
    shared = cell(image, 3, 3)
    np.testing.assert_array_equal(shared[STRIP:], expected_cell(EMPTY, 1, purple, "fixed")[STRIP:])
    assert (shared[: STRIP - 1, :5] == purple).all() and (shared[: STRIP - 1, 6:11] == red).all()
    assert (shared[STRIP - 1] == 0).all() and (shared[:STRIP, [5, 11]] == 0).all()
    # Agent 1 (blue, facing north) blended over its bonus tile.
    on_bonus = expected_cell(BONUS, 3, COLORS["blue"], "fixed")
    np.testing.assert_array_equal(cell(image, 6, 5), on_bonus)
    assert not (on_bonus == COLORS["yellow"]).all()


def test_render_map_draw_order_ties_and_fov():
    params = fixed_params()
    state = scene(params, arrival=[0, 0, 0])  # tie: lowest index (agent 0, red, east) wins
    image = render_map(state, params, tile=TILE)
    below_strip = cell(image, 3, 3)[STRIP:-1, 1:-1]
    np.testing.assert_array_equal(
        below_strip, expected_cell(EMPTY, 0, COLORS["red"], "fixed")[STRIP:-1, 1:-1]
    )
    # The field-of-view outline only touches cell edges: the wall colour survives inside the cells.
    assert (cell(image, 0, 0)[1:-1, 1:-1] == COLORS["worst"]).all()
    assert not np.array_equal(image, render_map(state, params, tile=TILE, fov=False))
    # At 3 pixels per cell the map is exactly the observation sprites.
    small = render_map(state, params, tile=3)
    assert small.shape == (39, 39, 3)
    np.testing.assert_array_equal(
        cell(small, 6, 5, 3), sprites.cell_sprite(BONUS, 3, COLORS["blue"], "fixed")
    )


def test_render_map_shows_every_agent_on_a_shared_cell():
    params = fixed_params()
    state = scene(params, arrival=[3, 1, 2])
    state = state.replace(pos=state.pos.at[1].set(state.pos[0]))  # all three on (3, 3); agent 1 drawn
    shared = cell(render_map(state, params, tile=TILE, fov=False), 3, 3)
    segments = [shared[0, 0:3], shared[0, 4:7], shared[0, 8:11]]  # 4 pixels each, the last one black
    for segment, name in zip(segments, ["blue", "purple", "red"], strict=True):
        assert (segment == COLORS[name]).all()
    np.testing.assert_array_equal(shared[STRIP:], expected_cell(EMPTY, 3, COLORS["blue"], "fixed")[STRIP:])
    # At 3 pixels per cell there is no room for a strip: the map is the observation sprites.
    small = render_map(state, params, tile=3, fov=False)
    np.testing.assert_array_equal(
        cell(small, 3, 3, 3), sprites.cell_sprite(EMPTY, 3, COLORS["blue"], "fixed")
    )


def test_a_marked_agent_is_framed_in_white_whatever_its_colour():
    """The learner of a video is framed in white (`marked`), under a shared cell's strip; other cells and
    unmarked agents are drawn as before."""
    params = fixed_params()
    state = scene(params)
    plain = render_map(state, params, tile=TILE, fov=False)
    marked = render_map(state, params, tile=TILE, fov=False, marked=(1,))
    width = max(2, TILE // 8)
    framed = cell(marked, 6, 5)  # agent 1, alone on bonus tile 1
    white = pictures.MARK_COLOR
    assert (framed[:width] == white).all() and (framed[:, -width:] == white).all()
    np.testing.assert_array_equal(
        framed[width:-width, width:-width], cell(plain, 6, 5)[width:-width, width:-width]
    )
    outside = np.ones(plain.shape[:2], bool)
    outside[5 * TILE : 6 * TILE, 6 * TILE : 7 * TILE] = False
    np.testing.assert_array_equal(marked[outside], plain[outside])  # nothing else changes
    shared = cell(render_map(state, params, tile=TILE, fov=False, marked=(0,)), 3, 3)  # agent 0 is not drawn
    np.testing.assert_array_equal(shared[:STRIP], cell(plain, 3, 3)[:STRIP])  # the strip stays on top
    assert (shared[STRIP:, :width] == white).all()
    np.testing.assert_array_equal(
        render_map(state, params, tile=3, marked=(1,)), render_map(state, params, tile=3)
    )


def test_render_map_prestige_colour():
    _, params = jaxsocial.make("goalcycle3", max_steps=5)
    image = render_map(scene(params, prestige=[0.0, 0.0, 20.0]), params, tile=3)
    r, _, b = cell(image, 3, 3, 3)[1, 1].astype(int)  # agent 2 (high prestige) is blue
    assert b > 150 and r < 10
    r, _, b = cell(image, 6, 5, 3)[1, 1].astype(int)  # agent 1 (no prestige) is red
    assert r > 150 and b == 0


def test_render_frame_and_rollout():
    env, params = jaxsocial.make("goalcycle3", max_steps=5)
    episode = rollout_episode(jax.random.key(0), params, "random-move")
    assert episode["steps"] == 5 and episode["truncated"]
    assert len(episode["states"]) == len(episode["obs"]) == 6 and len(episode["rewards"]) == 5
    np.testing.assert_allclose(episode["returns"], np.sum(episode["rewards"], 0))
    state, obs = episode["states"][-1], episode["obs"][-1]
    assert obs.shape == (3, 21, 21, 3)
    frame = render_frame(state, obs, params, episode["rewards"][-1], tile=TILE)
    map_h, map_w = 13 * TILE, 13 * TILE
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.shape[0] > map_h and frame.shape[1] > map_w + 21 * (TILE // 3)
    np.testing.assert_array_equal(frame, render_frame(state, None, params, episode["rewards"][-1], tile=TILE))
    frames = episode_frames(episode, params, tile=TILE)
    assert len(frames) == 6 and all(f.shape == frame.shape for f in frames)
    # Titles are light text in the band above the panels (4 pixels from the top), and only there.
    untitled = render_frame(state, obs, params, episode["rewards"][-1], tile=TILE, titles=["", "", ""])
    differs = np.any(frame != untitled, axis=-1)
    assert differs.any() and not differs[4 + title_height(TILE) :].any()
    assert np.all(frame[differs] >= np.minimum(untitled[differs], TITLE_COLOR))
    with pytest.raises(ValueError, match="2 titles for 3 agents"):
        render_frame(state, obs, params, tile=TILE, titles=["a", "b"])


def test_each_frame_names_its_step_and_every_agents_return_so_far(monkeypatch):
    assert agent_titles(["learner 0", "expert 1"], np.array([[1.0, 0.0], [0.0, -1.5]])) == [
        "learner 0: +1.0", "expert 1: -1.5"
    ]  # fmt: skip
    assert agent_titles(["agent 0"], np.zeros((0, 1))) == ["agent 0: +0.0"]  # before the first step
    _, params = jaxsocial.make("goalcycle3", max_steps=4)
    episode = rollout_episode(jax.random.key(0), params, "random-move")
    seen = []
    monkeypatch.setattr(pictures, "render_frame", lambda *a, titles, **k: seen.append(titles))
    episode_frames(episode, params, tile=TILE)
    assert seen[-1] == [f"agent {i}: {r:+.1f}" for i, r in enumerate(episode["returns"])]
    assert seen[0] == [f"agent {i}: +0.0" for i in range(3)]


def test_save_episode_checks_extension(tmp_path):
    frames = [np.zeros((8, 8, 3), np.uint8)] * 2
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        save_episode(frames, tmp_path / "x.png")
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        with pytest.raises(RuntimeError, match="pip install imageio-ffmpeg"):
            save_episode(frames, tmp_path / "x.mp4")
    path = tmp_path / "x.gif"
    save_episode([np.zeros((8, 8, 3), np.uint8), np.full((8, 8, 3), 255, np.uint8)], path, fps=4)
    assert iio.imread(path, index=None).shape == (2, 8, 8, 3)


def run_cli(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "jaxsocial.render", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_cli_writes_gif(tmp_path):
    out = tmp_path / "episode.gif"
    result = run_cli("--env", "goalcycle3", "--out", str(out), "--steps", "4", "--seed", "1", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert out.exists()
    frames = iio.imread(out, index=None)
    assert frames.ndim == 4 and frames.shape[0] > 1 and frames.shape[-1] == 3
    assert "goalcycle3" in result.stdout and "steps: 4" in result.stdout and str(out) in result.stdout
    assert result.stdout.count("penalties") == 3
    assert "next: watch a trained learner instead: --ckpt RUN_DIR" in result.stdout


def test_cli_scale_draws_every_panel_larger(tmp_path):
    args = cli.parse_args(["--env", "goalcycle3", "--out", str(tmp_path / "x.gif"), "--scale", "2"])
    assert args.tile == 2 * TILE
    params = fixed_params()
    small, large = (render_frame(scene(params), None, params, tile=t) for t in (TILE, args.tile))
    assert large.shape[1] == 2 * small.shape[1]  # every width in the layout doubles (titles set heights only)
    assert large.shape[0] > 2 * small.shape[0] - title_height(TILE)
    with pytest.raises(SystemExit):
        cli.parse_args(["--env", "goalcycle3", "--out", str(tmp_path / "x.gif"), "--scale", "0"])
    assert cli.parse_args(["--env", "goalcycle3", "--out", str(tmp_path / "x.gif")]).tile == 3 * TILE


def refused(argv: list[str]) -> str:
    """The one-line error `render` exits with on `argv` (no usage text: the flags parsed)."""
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    message = str(e.value)
    assert message.startswith("python -m jaxsocial.render: error: ") and "usage" not in message, message
    return message


def test_cli_unknown_env(tmp_path):
    result = run_cli("--env", "nope", "--out", str(tmp_path / "x.gif"), cwd=tmp_path)
    assert result.returncode == 1 and "usage" not in result.stderr
    assert "unknown environment 'nope'" in result.stderr and "goalcycle3" in result.stderr
    assert not (tmp_path / "x.gif").exists()


def test_cli_refuses_to_overwrite_and_bad_extension(tmp_path):
    out = tmp_path / "exists.gif"
    out.write_bytes(b"keep me")
    assert "--overwrite" in refused(["--env", "goalcycle3", "--out", str(out)])
    assert out.read_bytes() == b"keep me"
    assert ".gif or .mp4" in refused(["--env", "goalcycle3", "--out", str(tmp_path / "x.avi")])


@pytest.fixture
def learner_run(two_seed_run):
    """TINY's two-seed run (slots learner,random,random; aux 'pred'); its seeds are run/s0, run/s1."""
    return two_seed_run


def test_cli_plays_a_saved_learner_with_the_runs_slots(learner_run, tmp_path, capsys):
    out, random_out = tmp_path / "learner.gif", tmp_path / "random.gif"
    # In the run's environment (max_steps=6) with the run's slots: the episode ends after 6 steps.
    assert cli.main(["--ckpt", str(learner_run / "s0"), "--out", str(out), "--steps", "100"]) == 0
    stdout = capsys.readouterr().out
    assert "slots learner,random,random" in stdout and "decoder's output beside its view" in stdout
    assert "steps: 6 (time limit)" in stdout and "wrote 6 frames" in stdout
    # it ends with the command that measures the learner over many episodes, in the run's environment
    assert f"next: its return over many episodes: python -m jaxsocial.evaluate --ckpt {learner_run / 's0'} " \
        f"--env {TINY.env}:{TINY_ENV_ARGS}" in stdout  # fmt: skip
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 6
    assert cli.main(["--env", TINY.env + ":" + TINY_ENV_ARGS, "--out", str(random_out), "--steps", "5"]) == 0
    random_frames = iio.imread(random_out, index=None)
    assert random_frames.shape[0] == 6  # 5 steps and the final state
    # The same layout, with one more panel: the learner's predicted view.
    assert frames.shape[1] == random_frames.shape[1] and frames.shape[2] > random_frames.shape[2]


def test_cli_writes_into_the_run_by_default_so_pictures_never_collide(
    learner_run, tmp_path, capsys, monkeypatch
):
    run = tmp_path / "run"
    shutil.copytree(learner_run / "s0", run)
    titles = []
    video = playback.episode_video
    monkeypatch.setattr(playback, "episode_video", lambda *a: titles.append(a[-1]) or video(*a))
    assert cli.main(["--ckpt", str(run), "--steps", "3"]) == 0
    assert titles == ["predicted next view"]  # the decoder panel's title follows the aux loss ('pred' here)
    assert DECODER_TITLES["rec"] == "reconstructed view"
    assert (run / "learner.gif").is_file() and f"to {run / 'learner.gif'}" in capsys.readouterr().out
    spec = f"{TINY.env}:{TINY_ENV_ARGS}"
    assert cli.main(["--ckpt", str(run), "--env", spec, "--steps", "3"]) == 0
    assert (run / f"learner-{cli.gif_name(spec)}.gif").is_file()
    assert "give --out FILE" in refused(["--env", TINY.env])
    assert [cli.counted(n, "reward") for n in (0, 1, 2)] == ["0 rewards", "1 reward", "2 rewards"]
    assert cli.counted(1, "penalty", "penalties") == "1 penalty"


def test_predicted_view_beside_the_learners_view(learner_run):
    spec = f"{TINY.env}:{TINY_ENV_ARGS}"
    episode = playback.play_episode(
        playback.episode_setup(str(learner_run / "s0"), spec, TINY_SLOTS), steps=6
    )
    assert episode["learner"] == 0 and episode["actions"].shape == (6, 3) and episode["truncated"][-1]
    predicted = playback.predicted_views(episode)
    assert predicted.shape == (6, 21, 21, 3) and predicted.dtype == np.uint8
    plain = playback.episode_video(episode, TILE)
    shown = playback.episode_video(episode, TILE, predicted)
    assert len(shown) == len(plain) == 6
    # Panels sit right of the 7x7 map, 4 pixels apart: an 84-pixel view under its title and a 3-pixel strip,
    # in a 2-pixel border.
    gap, border, side, strip = 4, 2, 84, 3
    top = gap + title_height(TILE)
    panel = [2 * gap + 7 * TILE + k * (side + 2 * border + gap) + border for k in range(4)]

    def view(frame, k):
        return frame[top + border + strip : top + border + strip + side, panel[k] : panel[k] + side]

    for t in (0, 5):
        assert shown[t].shape == (plain[t].shape[0], plain[t].shape[1] + side + 2 * border + gap, 3)
        np.testing.assert_array_equal(view(shown[t], 0), upscale(episode["obs"][t, 0], 1, 4))
        np.testing.assert_array_equal(view(shown[t], 1), upscale(predicted[t], 1, 4))
        np.testing.assert_array_equal(view(shown[t], 2), view(plain[t], 1))  # agent 1's view, moved right
    first = jax.tree.map(lambda x: x[0], episode["states"])
    with pytest.raises(ValueError, match="predicted view must be uint8"):
        render_frame(first, None, episode["env_params"], predicted={0: predicted[0].astype(np.float32)})


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--ckpt", "{tmp}/nope"], "does not exist"),
        (["--ckpt", "{tmp}"], "is not a run directory"),
        (["--ckpt", "{run}"], "holds 2 seeds: pass one of them, e.g. --ckpt {run}/s0"),
        (["--ckpt", "{run}/s0", "--env", "goalcycle3:observation=symbolic"], "the network takes 'rgb' ones"),
        (
            ["--ckpt", "{run}/s0", "--env", "goalcycle3:view_size=5"],
            "takes observations of shape (21, 21, 3)",
        ),
        (["--ckpt", "{run}/s0", "--env", "goalcycle3-solo"], "the run's slots do not fit goalcycle3-solo"),
        (
            ["--ckpt", "{run}/s0", "--env", "fourrooms", "--slots", "learner,expert:explorer,random"],
            "explorer",
        ),
        (["--ckpt", "{run}/s0", "--policy", "random"], "--policy is for random actions"),
        (["--env", "goalcycle3", "--slots", "learner,random,random"], "--slots needs --ckpt"),
    ],
)
def test_cli_ckpt_errors_before_compiling(learner_run, tmp_path, monkeypatch, args, message):
    def must_not_run(*_):
        raise AssertionError("played an episode")

    monkeypatch.setattr(playback, "_play", must_not_run)
    monkeypatch.setattr(cli, "rollout_episode", must_not_run)
    out = tmp_path / "x.gif"
    error = refused([a.format(tmp=tmp_path, run=learner_run) for a in args] + ["--out", str(out)])
    assert message.format(run=learner_run) in error
    assert not out.exists()
