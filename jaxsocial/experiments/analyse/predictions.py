"""A trained learner's predicted next frames (paper Fig. 2): at a step of an episode beside the experts,
the decoder's prediction of the next observation for each movement action, beside the observed frame and
the frame that followed. The episode is played by `jaxsocial.playback`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxsocial.agents import network
from jaxsocial.env.types import FORWARD, LEFT, RIGHT
from jaxsocial.playback import episode_setup, play_episode

MOVES = {"left": LEFT, "right": RIGHT, "forward": FORWARD}
WARM_UP = 8
"""`predicted_frames` picks a step after this many by default."""


def learner_episode(
    run_dir: str, env_spec: str, steps: int = 40, seed: int = 0, slots: str | None = None
) -> dict[str, Any]:
    """`play_episode` of `episode_setup(run_dir, env_spec, slots)`: by default the learner saved in `run_dir`
    in slot 0 of `env_spec` beside the environment's default companions."""
    return play_episode(episode_setup(run_dir, env_spec, slots), steps, seed)


def predicted_frames(episode: dict[str, Any], step: int | None = None) -> dict[str, Any]:
    """The learner's predicted next views at one step of a `learner_episode`: by default the step at which
    its view shows the most agent pixels (after `WARM_UP` steps).

    Returns {'step': t, 'observed': uint8[21, 21, 3] its view at t, 'next': its view after the step,
    'action': the action it took, 'predicted': {move: float32[21, 21, 3] in [0, 1]} the decoder's prediction
    for each movement action}. Raises ValueError if the network has no decoder (aux='none').
    """
    learner = episode["learner"]
    views = episode["obs"][:, learner]
    if step is None:  # after the LSTM has seen a few steps
        warm = min(WARM_UP, len(views) - 1)
        step = warm + int(np.argmax([_agent_pixels(v) for v in views[warm:]]))
    moves = jnp.asarray(list(MOVES.values()))
    hidden = jnp.broadcast_to(episode["hidden"][step], (len(MOVES), episode["hidden"].shape[-1]))
    frames = np.clip(np.asarray(network.decode(episode["params"], episode["net"], hidden, moves)), 0.0, 1.0)
    return {
        "step": step,
        "observed": views[step],
        "next": episode["next_obs"][step, learner],
        "action": int(episode["actions"][step, learner]),
        "predicted": dict(zip(MOVES, frames, strict=True)),
    }


def _agent_pixels(frame: np.ndarray) -> int:
    """Pixels that are saturated in red or blue and not yellow (agents are drawn red to blue)."""
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return int(np.sum((np.maximum(r, b) > 150) & (g < 100)))


def draw(runs, path: Path, env_spec: str) -> None:
    """The figure for the `predictions` recipe: the first seed of its first condition, in `env_spec` (the
    scale's 3-goal Goal Cycle, `kinds.draw_predictions`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    condition = runs.recipe.conditions[0]
    run_dir = runs.seed_dirs[condition][0]
    fig = frames_figure(predicted_frames(learner_episode(str(run_dir), env_spec)), str(run_dir))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def frames_figure(out: dict[str, Any], title: str):
    """A matplotlib figure of a `predicted_frames` result: the view at t, the decoder's prediction for each
    movement action and the view at t+1, side by side on one colour scale (views as uint8 / 255, the
    decoder's target scale)."""
    import matplotlib.pyplot as plt

    names = {v: k for k, v in MOVES.items()}
    panels = [("observed (t)", out["observed"] / 255.0)]
    panels += [(f"predicted: {m}", f) for m, f in out["predicted"].items()]
    panels += [(f"observed (t+1), took {names.get(out['action'], out['action'])}", out["next"] / 255.0)]
    fig, axes = plt.subplots(1, len(panels), figsize=(2.4 * len(panels), 2.8))
    for ax, (label, frame) in zip(axes, panels, strict=True):
        ax.imshow(frame, interpolation="nearest", vmin=0.0, vmax=1.0)
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    fig.suptitle(f"{title}, step {out['step']}", fontsize=8)
    fig.tight_layout()
    return fig
