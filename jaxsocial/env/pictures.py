"""Pictures and videos of episodes for people (numpy + imageio, outside jit; `jaxsocial.render` is its CLI).

`render_map` draws the whole grid with every agent as in the observations (docs/environment.md 4.5, 4.6,
5): 3x3-pixel cell pictures from `sprites`, upscaled nearest-neighbour to `tile` pixels per cell.
`render_frame` puts the map next to each agent's egocentric view (and, optionally, a learner's predicted
view); `rollout_episode` plays one episode and `save_episode` writes a GIF or an MP4.

Each panel has a title: the map's gives the step ("step t of T"), a view's its agent ("agent i", "learner's
view", or as the caller names them: `agent_titles` adds each agent's return so far), "predicted next view".
Each agent's field of view is outlined on the map, and a strip above its view, in its identity colour
(marlgrid's default agent colours: red, blue, purple, orange, olive, pink, by index). A view's border turns
green on a step with a positive reward and red on a penalty. A predicted view has a striped strip. A cell
holding several agents shows one of them (as the observations do) and a strip along its top with a segment
per agent, in their current colours. A grey bar along the bottom of a frame shows the elapsed fraction of
`max_steps`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import imageio.v2 as imageio_v2
import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from jaxsocial.env import sprites
from jaxsocial.env.core import reset, step_env
from jaxsocial.env.observe import color_index, rgb, view_offsets
from jaxsocial.env.types import FORWARD, LEFT, NUM_ACTIONS, RIGHT, TILE_COLORS, EnvParams, EnvState

BACKGROUND = np.array((40, 40, 40), np.uint8)
"""Separators and frame background."""
PROGRESS = np.array((130, 130, 130), np.uint8)
REWARD_BORDER = {1: np.array((0, 255, 0), np.uint8), -1: np.array((255, 0, 0), np.uint8)}
NO_REWARD_BORDER = np.array((70, 70, 70), np.uint8)
FOV_ALPHA = 0.6
"""Opacity of the field-of-view outline."""
VIDEO_EXTENSIONS = (".gif", ".mp4")
POLICIES = ("random", "random-move")
TITLE_COLOR = (220, 220, 220)
PREDICTED_TITLE = "predicted next view"
DECODER_TITLES = {"pred": PREDICTED_TITLE, "rec": "reconstructed view"}
"""The decoder panel's title by the network's frame loss (`NetworkConfig.frame_aux`)."""


def title_font(tile: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's built-in font, sized so that "predicted next view" fits over a view at `tile` pixels per
    cell."""
    return ImageFont.load_default(size=max(8, round(tile * 0.75)))


def title_height(tile: int) -> int:
    """Pixel rows of a panel title at `tile` pixels per cell (the text and a gap below it)."""
    return math.ceil(title_font(tile).getbbox("Agpv'")[3]) + max(2, tile // 6)


def identity_colors(n: int) -> np.ndarray:
    """uint8[n, 3] a fixed colour per agent index, used to tell agents apart (FOV outline, view strip)."""
    return np.array(sprites.fixed_palette()[:n], np.uint8)


def agent_colors(state: EnvState, env_params: EnvParams) -> np.ndarray:
    """uint8[N, 3] each agent's current sprite colour (its prestige colour, or its fixed colour)."""
    palette = sprites.prestige_palette() if env_params.agent_colors == "prestige" else sprites.fixed_palette()
    idx = np.asarray(color_index(state, env_params))
    return np.array([palette[i] for i in idx], np.uint8)


def _as_numpy(state: EnvState) -> EnvState:
    state = jax.device_get(state)
    if np.ndim(state.grid) != 2:
        raise ValueError(f"render one environment at a time; got grid of shape {np.shape(state.grid)}")
    return state


def cell_agents(state: EnvState) -> dict[tuple[int, int], list[int]]:
    """{(x, y): agent indices} the present agents on each occupied cell, the drawn one first: earliest
    arrival, ties to the lowest index (absent agents are not drawn)."""
    pos, arrival, present = np.asarray(state.pos), np.asarray(state.arrival), np.asarray(state.present)
    cells: dict[tuple[int, int], list[int]] = {}
    for i in sorted(map(int, np.flatnonzero(present)), key=lambda i: (arrival[i], i)):
        cells.setdefault((int(pos[i, 0]), int(pos[i, 1])), []).append(i)
    return cells


def upscale(image: np.ndarray, cell: int, tile: int) -> np.ndarray:
    """uint8[h*cell, w*cell, C] -> uint8[h*tile, w*tile, C]: nearest-neighbour, cell by cell (`tile >= 1`)."""

    def index(n_cells):
        px = np.arange(n_cells * tile)
        return (px // tile) * cell + (px % tile) * cell // tile

    return image[index(image.shape[0] // cell)][:, index(image.shape[1] // cell)]


def _outline(image: np.ndarray, y0: int, x0: int, y1: int, x1: int, color: np.ndarray, alpha: float) -> None:
    """Blend a 1-pixel rectangle outline (inclusive pixel bounds) into `image` in place."""
    mask = np.zeros(image.shape[:2], bool)
    mask[y0, x0 : x1 + 1] = mask[y1, x0 : x1 + 1] = True
    mask[y0 : y1 + 1, x0] = mask[y0 : y1 + 1, x1] = True
    blended = (1 - alpha) * image[mask].astype(np.float64) + alpha * color.astype(np.float64)
    image[mask] = np.round(blended).astype(np.uint8)


def _shared_strip(cell: np.ndarray, colors: np.ndarray) -> None:
    """Draw, in place, a strip along the top of a uint8[tile, tile, 3] cell: one segment per colour of
    uint8[k, 3], with a black pixel after each segment (where segments are wider than 1 pixel) and a black
    row below."""
    height = max(2, cell.shape[0] // 4)
    cell[:height] = 0
    for color, px in zip(colors, np.array_split(np.arange(cell.shape[1]), len(colors)), strict=True):
        cell[: height - 1, px[0] : px[-1] + (len(px) == 1)] = color


MARK_COLOR = np.array((255, 255, 255), np.uint8)
"""The frame around a marked agent's cell on the map (the learner in a trained learner's video)."""


def _frame(cell: np.ndarray, width: int) -> None:
    """Paint, in place, a `MARK_COLOR` frame `width` pixels wide along the edges of a uint8[tile, tile, 3]
    cell."""
    cell[:width], cell[-width:], cell[:, :width], cell[:, -width:] = (
        MARK_COLOR,
        MARK_COLOR,
        MARK_COLOR,
        MARK_COLOR,
    )


def render_map(
    state: EnvState, env_params: EnvParams, tile: int = 12, fov: bool = True, marked: Sequence[int] = ()
) -> np.ndarray:
    """The whole map as uint8[H * tile, W * tile, 3] (rows along y).

    Tiles are flat colours (wall (74, 65, 42), bonus yellow, goal green, empty black); each occupied cell
    shows one agent (earliest arrival, ties to the lowest index) as a triangle pointing in its absolute
    direction, in its current colour, blended over a bonus tile or goal exactly as in the observations.
    With `tile >= 6`, a cell holding k > 1 agents gets a black strip along its top with k segments, one per
    agent (drawn one first) in its current colour; with `fov` too, each active agent's field of view gets a
    thin outline in its identity colour. With `tile >= 6`, the cell of each present agent in `marked` gets
    a white frame (`MARK_COLOR`, `max(2, tile // 8)` pixels wide, under any shared-cell strip), so that agent
    can be found at a glance whatever its prestige colour.
    """
    if tile < 1:
        raise ValueError(f"tile={tile} must be >= 1")
    state = _as_numpy(state)
    grid = np.asarray(state.grid)
    t = sprites.TILE
    image = upscale(TILE_COLORS[grid], 1, t)  # [H * 3, W * 3, 3]
    colors = agent_colors(state, env_params)
    directions = np.asarray(state.dir)
    cells = cell_agents(state)
    for (x, y), (i, *_) in cells.items():
        color = tuple(int(c) for c in colors[i])
        cell = sprites.cell_sprite(int(grid[y, x]), int(directions[i]), color, env_params.agent_colors)
        image[y * t : (y + 1) * t, x * t : (x + 1) * t] = cell
    image = upscale(image, t, tile)
    if tile >= 6:
        for (x, y), agents in cells.items():
            if set(agents) & set(marked):
                _frame(image[y * tile : (y + 1) * tile, x * tile : (x + 1) * tile], max(2, tile // 8))
        for (x, y), agents in cells.items():
            if len(agents) > 1:
                _shared_strip(image[y * tile : (y + 1) * tile, x * tile : (x + 1) * tile], colors[agents])
    if fov and tile >= 6:
        height, width = grid.shape
        offsets = view_offsets(env_params.view_size, env_params.view_offset)
        for i, color in enumerate(identity_colors(len(directions))):
            if not np.asarray(state.active)[i]:
                continue
            cells = np.asarray(state.pos)[i] + offsets[directions[i]].reshape(-1, 2)
            (xa, ya), (xb, yb) = cells.min(0).clip(0), cells.max(0).clip(None, [width - 1, height - 1])
            _outline(image, ya * tile, xa * tile, (yb + 1) * tile - 1, (xb + 1) * tile - 1, color, FOV_ALPHA)
    return image


def _spacing(tile: int) -> tuple[int, int, int]:
    """Pixel sizes of a frame at `tile` pixels per map cell: the gap between panels, a view's border and the
    strip above a view."""
    return max(2, tile // 3), max(1, tile // 6), max(2, tile // 4)


def _view_panels(
    obs: np.ndarray,
    reward: np.ndarray | None,
    tile: int,
    predicted: Mapping[int, np.ndarray],
    titles: Sequence[str],
    predicted_title: str,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, str]]:
    """`render_frame`'s panels in order: each agent's view and, right after it, the view its network predicts
    if any. Each is (view uint8[21, 21, 3], strip colour uint8[3] or a striped strip uint8[side, 3], border
    colour uint8[3], title)."""
    n = obs.shape[0]
    ids = identity_colors(n)
    signs = np.zeros(n, int) if reward is None else np.sign(np.asarray(reward, np.float64)).astype(int)
    striped = np.arange(obs.shape[2] * max(1, tile // 3)) // _spacing(tile)[2] % 2 == 0
    panels = []
    for i in range(n):
        panels.append((obs[i], ids[i], REWARD_BORDER.get(signs[i], NO_REWARD_BORDER), titles[i]))
        if i in predicted:
            view = np.asarray(predicted[i])
            if view.shape != obs.shape[1:] or view.dtype != np.uint8:
                expected = f"uint8{list(obs.shape[1:])}"
                raise ValueError(
                    f"agent {i}'s predicted view must be {expected}, not {view.dtype}{list(view.shape)}"
                )
            striped_strip = np.where(striped[:, None], ids[i], BACKGROUND)
            panels.append((view, striped_strip, NO_REWARD_BORDER, predicted_title))
    return panels


def _grid_shape(n_panels: int, fit: int) -> tuple[int, int]:
    """(rows, columns) of `n_panels` panels in columns of at most `fit` (at least 1) rows, as few columns as
    that allows, and then as few rows as those columns need."""
    rows = max(1, min(n_panels, fit))
    cols = math.ceil(n_panels / rows)
    return math.ceil(n_panels / cols), cols


def _compose(
    world: np.ndarray,
    panels: list[tuple[np.ndarray, np.ndarray, np.ndarray, str]],
    tile: int,
    map_title: str,
    progress: float,
) -> np.ndarray:
    """The frame uint8[h, w, 3] of the map `world` uint8[H * tile, W * tile, 3] titled `map_title`, the
    `panels` (`_view_panels`) in a grid to its right, and a progress bar `progress` (in [0, 1]) wide below."""
    map_h, map_w = world.shape[:2]
    gap, border, strip = _spacing(tile)
    label = title_height(tile)
    views = np.stack([upscale(v, 1, max(1, tile // 3)) for v, *_ in panels])
    side = views.shape[1]
    panel_h, panel_w = label + strip + side + 2 * border, side + 2 * border
    rows, cols = _grid_shape(len(panels), (label + map_h + gap) // (panel_h + gap))
    content_h = max(label + map_h, rows * panel_h + (rows - 1) * gap)
    bar = max(2, gap // 2)
    height = gap + content_h + gap + bar + gap
    width = gap + map_w + gap + cols * panel_w + (cols - 1) * gap + gap
    frame = np.empty((height, width, 3), np.uint8)
    frame[:] = BACKGROUND
    frame[gap + label : gap + label + map_h, gap : gap + map_w] = world
    placed = [((gap, gap), map_title)]

    for k, ((_, strip_colors, border_color, title), view) in enumerate(zip(panels, views, strict=True)):
        r, c = divmod(k, cols)
        y0 = gap + r * (panel_h + gap)
        x0 = 2 * gap + map_w + c * (panel_w + gap)
        placed.append(((x0, y0), title))
        y0 += label
        frame[y0 : y0 + panel_h - label, x0 : x0 + panel_w] = border_color
        frame[y0 + border : y0 + border + strip, x0 + border : x0 + border + side] = strip_colors
        frame[y0 + border + strip : y0 + border + strip + side, x0 + border : x0 + border + side] = view

    bar_y = gap + content_h + gap
    frame[bar_y : bar_y + bar, gap : gap + round(progress * (width - 2 * gap))] = PROGRESS
    return _draw_titles(frame, placed, tile)


def _draw_titles(frame: np.ndarray, placed: list[tuple[tuple[int, int], str]], tile: int) -> np.ndarray:
    """`frame` uint8[h, w, 3] with each `(x, y), title` of `placed` written at (x, y) (its top left)."""
    image = Image.fromarray(frame)
    draw, font = ImageDraw.Draw(image), title_font(tile)
    for xy, title in placed:
        draw.text(xy, title, fill=TITLE_COLOR, font=font)
    return np.asarray(image)


def render_frame(
    state: EnvState,
    obs: np.ndarray | None,
    env_params: EnvParams,
    reward: np.ndarray | None = None,
    tile: int = 12,
    predicted: Mapping[int, np.ndarray] | None = None,
    titles: Sequence[str] | None = None,
    predicted_title: str = PREDICTED_TITLE,
    marked: Sequence[int] = (),
) -> np.ndarray:
    """One video frame, uint8[h, w, 3]: the map on the left, every agent's view on the right, each panel
    under its title.

    Args:
        obs: uint8[N, 21, 21, 3] RGB observations of `state`; None (or symbolic observations) re-renders them.
        reward: float[N] the reward each agent received on the step into `state`; it colours the view borders.
        tile: map pixels per cell; views are upscaled to the same size per cell (`max(1, tile // 3)`).
        predicted: {agent index: uint8[21, 21, 3]} a view an agent's network predicts, drawn as one more
            panel ("predicted next view") right after that agent's view ("learner's view"), with a striped
            strip in its identity colour.
        titles: the N agents' view titles (default "learner's view" for agents in `predicted`, else
            "agent i").
        predicted_title: the title over a `predicted` panel (`DECODER_TITLES`: "reconstructed view" for a
            reconstruction loss).
        marked: agents framed in white on the map (`render_map`), e.g. the learner.
    """
    state = _as_numpy(state)
    if obs is None or np.ndim(obs) != 4 or np.shape(obs)[-1] != 3:
        obs = rgb(state, env_params)
    obs = np.asarray(obs, np.uint8)
    n = obs.shape[0]
    predicted = predicted or {}
    if titles is None:
        titles = ["learner's view" if i in predicted else f"agent {i}" for i in range(n)]
    if len(titles) != n:
        raise ValueError(f"{len(titles)} titles for {n} agents")
    world = render_map(state, env_params, tile, marked=marked)
    panels = _view_panels(obs, reward, tile, predicted, titles, predicted_title)
    map_title = f"step {int(np.asarray(state.time))} of {env_params.max_steps}"
    progress = min(1.0, float(np.asarray(state.time)) / env_params.max_steps)
    return _compose(world, panels, tile, map_title, progress)


_reset = jax.jit(reset)
_step_env = jax.jit(step_env)

Policy = Callable[[jax.Array, jax.Array, EnvState], Any]


def _chooser(policy: str | Policy, key: jax.Array, limit: int, n: int) -> Callable[[int, Any, EnvState], Any]:
    """`rollout_episode`'s `choose(t, obs, state)`: the n agents' int32[n] actions at step t < `limit` by
    `policy` (a name of `POLICIES`, whose actions are drawn with `key` beforehand, or a callable, given
    `key`'s t-th split)."""
    if callable(policy):
        step_keys = jax.random.split(key, limit)

        def choose(t, obs, state):
            return np.asarray(policy(step_keys[t], obs, state), np.int32)

    elif policy in POLICIES:
        moves = np.arange(NUM_ACTIONS) if policy == "random" else np.array([LEFT, RIGHT, FORWARD])
        drawn = moves[np.asarray(jax.random.randint(key, (limit, n), 0, len(moves)))].astype(np.int32)

        def choose(t, obs, state):
            return drawn[t]

    else:
        raise ValueError(f"unknown policy {policy!r}; use one of {POLICIES} or a callable")
    return choose


def rollout_episode(
    key: jax.Array,
    env_params: EnvParams,
    policy: str | Policy = "random",
    max_steps: int | None = None,
) -> dict[str, Any]:
    """Play one episode (no auto-reset) with a jitted `step_env` in a Python loop.

    Args:
        policy: 'random' (uniform over all 7 actions), 'random-move' (uniform over left, right, forward) or
            a callable `(key, obs, state) -> int[N]` actions.
        max_steps: stop after this many steps at most (default `env_params.max_steps`); the episode also ends
            when every agent is terminated or the time limit truncates it.
    Returns:
        dict with 'states' (list of T+1 numpy `EnvState`), 'obs' (list of T+1 uint8[N, ...]), 'actions' and
        'rewards' (lists of T int32[N] / float32[N]), 'returns' float32[N], 'steps' T, 'terminated' bool[N],
        'truncated' bool (the time limit ended the episode).
    """
    limit = env_params.max_steps if max_steps is None else max_steps
    if limit < 1:
        raise ValueError(f"max_steps={max_steps} must be >= 1")
    k_reset, k_act = jax.random.split(key)
    n = env_params.n_agents
    choose = _chooser(policy, k_act, limit, n)
    obs, state = jax.device_get(_reset(k_reset, env_params))
    states, observations, actions, rewards = [state], [obs], [], []
    terminated, truncated = np.zeros(n, bool), False
    for t in range(limit):
        act = choose(t, obs, state)
        out = _step_env(state, jnp.asarray(act), env_params)
        obs, state, reward, terminated, truncated = jax.device_get(out)
        states.append(state)
        observations.append(obs)
        actions.append(act)
        rewards.append(reward)
        if truncated or terminated.all():
            break
    returns = np.sum(rewards, axis=0, dtype=np.float32) if rewards else np.zeros(n, np.float32)
    return {
        "states": states,
        "obs": observations,
        "actions": actions,
        "rewards": rewards,
        "returns": returns,
        "steps": len(rewards),
        "terminated": np.asarray(terminated),
        "truncated": bool(truncated),
    }


def agent_titles(names: Sequence[str], rewards: np.ndarray) -> list[str]:
    """Each agent's view title: its name and its return so far, the sum of `rewards` float[t, N] (the steps
    before the frame): 'expert 1: +12.5'."""
    returns = np.asarray(rewards, np.float64).reshape(-1, len(names)).sum(0)
    return [f"{name}: {value:+.1f}" for name, value in zip(names, returns, strict=True)]


def episode_frames(episode: dict[str, Any], env_params: EnvParams, tile: int = 12) -> list[np.ndarray]:
    """`render_frame` for every state of a `rollout_episode` result (T+1 uint8 frames), each agent titled
    with its return so far."""
    rewards = np.asarray(episode["rewards"]).reshape(-1, env_params.n_agents)
    names = [f"agent {i}" for i in range(env_params.n_agents)]
    return [
        render_frame(
            s, o, env_params, rewards[t - 1] if t else None, tile, titles=agent_titles(names, rewards[:t])
        )
        for t, (s, o) in enumerate(zip(episode["states"], episode["obs"], strict=True))
    ]


def check_video_path(path: str | os.PathLike) -> str:
    """The lower-case extension of a video path; raises for unsupported ones or a missing MP4 writer."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in VIDEO_EXTENSIONS:
        raise ValueError(f"unsupported video file {os.fspath(path)!r}: use a .gif or .mp4 extension")
    if ext == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError as e:
            raise RuntimeError(
                "writing MP4 needs the ffmpeg plugin of imageio: pip install imageio-ffmpeg (or write a .gif)"
            ) from e
    return ext


def save_episode(frames: Sequence[np.ndarray], path: str | os.PathLike, fps: float = 8) -> None:
    """Write uint8[h, w, 3] frames as an (endlessly looping) GIF, or as an MP4 when `path` ends with .mp4.

    MP4 needs `imageio-ffmpeg`; frames are padded with black to a multiple of 16 pixels for the codec.
    """
    ext = check_video_path(path)
    if not frames:
        raise ValueError("no frames to save")
    if fps <= 0:
        raise ValueError(f"fps={fps} must be > 0")
    stack = np.stack([np.asarray(f, np.uint8) for f in frames])
    if ext == ".gif":
        iio.imwrite(path, stack, extension=".gif", duration=1000.0 / fps, loop=0)
    else:
        pad_h, pad_w = (-stack.shape[1]) % 16, (-stack.shape[2]) % 16
        stack = np.pad(stack, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)))
        imageio_v2.mimwrite(path, list(stack), format="FFMPEG", fps=fps, macro_block_size=16)
