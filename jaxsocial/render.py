"""Render one episode of random actions to a GIF or MP4.

    python -m jaxsocial.render --env goalcycle3 --out goalcycle3.gif [--seed 0] [--steps 100] [--fps 8]

Each frame shows the whole map (agents as triangles in their current colour, fields of view outlined in each
agent's identity colour) and every agent's egocentric view (border green on a reward, red on a penalty).
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import numpy as np

import jaxsocial
from jaxsocial.env.render import POLICIES, check_video_path, episode_frames, rollout_episode, save_episode


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.render", description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True, help=f"one of: {', '.join(jaxsocial.registered_envs())}")
    parser.add_argument("--out", required=True, help="output file, .gif or .mp4 (.mp4 needs imageio-ffmpeg)")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument(
        "--steps", type=int, default=None, help="at most this many steps (default: the env's max_steps)"
    )
    parser.add_argument("--fps", type=float, default=8.0, help="frames per second (default 8)")
    parser.add_argument("--tile", type=int, default=12, help="map pixels per cell (default 12)")
    parser.add_argument(
        "--policy",
        choices=POLICIES,
        default="random-move",
        help="random: all 7 actions; random-move (default): turn or forward",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    args = parser.parse_args(argv)

    # Everything is checked before JAX compiles anything.
    try:
        _, args.params = jaxsocial.make(args.env)
        check_video_path(args.out)
    except (ValueError, RuntimeError) as e:
        parser.error(str(e))
    if os.path.exists(args.out) and not args.overwrite:
        parser.error(f"{args.out} already exists; pass --overwrite to replace it")
    if args.steps is not None and args.steps < 1:
        parser.error(f"--steps {args.steps} must be >= 1")
    if args.fps <= 0:
        parser.error(f"--fps {args.fps} must be > 0")
    if args.tile < 3:
        parser.error(f"--tile {args.tile} must be >= 3")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    params = args.params
    episode = rollout_episode(jax.random.key(args.seed), params, args.policy, args.steps)
    frames = episode_frames(episode, params, args.tile)
    parent = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(parent, exist_ok=True)
    save_episode(frames, args.out, args.fps)

    rewards = np.array(episode["rewards"]).reshape(-1, params.n_agents)
    ending = (
        "all agents finished"
        if episode["terminated"].all()
        else ("time limit" if episode["truncated"] else "step cap")
    )
    print(f"env: {args.env} (seed {args.seed}, {args.policy} policy)")
    print(f"steps: {episode['steps']} ({ending})")
    for i in range(params.n_agents):
        print(
            f"agent {i}: return {episode['returns'][i]:+.3f}, "
            f"{int((rewards[:, i] > 0).sum())} rewards, {int((rewards[:, i] < 0).sum())} penalties"
        )
    print(f"wrote {len(frames)} frames to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
