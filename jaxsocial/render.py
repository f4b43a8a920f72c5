"""Render one episode to a GIF or MP4: random actions, or a trained learner beside its companions.

    python -m jaxsocial.render --env goalcycle3 --out goalcycle3.gif [--seed 0] [--steps 100] [--fps 8]
    python -m jaxsocial.render --ckpt runs/goalcycle3-s0 [--env goalcycle3] [--out learner.gif] --scale 2

Each frame shows, under their titles, the whole map (agents as triangles in their current colour, fields of
view outlined in each agent's identity colour, a strip of coloured segments on a cell several agents share)
and every agent's egocentric view (border green on a reward, red on a penalty).

With `--ckpt RUN_DIR` (one seed's run directory) the run's learner plays with its saved policy and the
other slots act as configured in the run (e.g. scripted experts; `--slots` overrides them), in the run's
environment unless `--env` names another (NAME or NAME:field=value,...). If its network has a decoder
(aux 'pred' or 'rec', trained with PPO), the decoder's output for the action taken (the predicted next view,
or the reconstructed view) is drawn beside the learner's view, with a striped strip. Such a video has a
frame per step; a random-action one also shows the final state.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import numpy as np

from jaxsocial import playback
from jaxsocial.agents import network, population
from jaxsocial.env import registry
from jaxsocial.env.pictures import (
    DECODER_TITLES,
    POLICIES,
    PREDICTED_TITLE,
    check_video_path,
    episode_frames,
    rollout_episode,
    save_episode,
)
from jaxsocial.run import rundir
from jaxsocial.specs import EnvSpec, PolicyRef


def learner_setup(ckpt: str, env: str | None, slots: str | None) -> tuple[playback.EpisodeSetup, str, bool]:
    """The episode set-up of `--ckpt RUN_DIR[#k]`, its env spec and whether to draw its decoder's output.
    ValueError, before anything compiles, for a directory that is not one seed's run or an env the policy
    cannot act in."""
    run_dir = PolicyRef.parse(ckpt).run
    dirs = rundir.written_seed_dirs(run_dir)
    if len(dirs) > 1:
        raise ValueError(f"{run_dir} holds {len(dirs)} seeds: pass one of them, e.g. --ckpt {dirs[0]}")
    config = rundir.read_config(run_dir)
    spec = env or f"{config['env']}:{config.get('env_args', '')}"
    if slots is None and config.get("slots"):  # else the environment's default companions, as in training
        try:
            parsed = EnvSpec.parse(spec)
            population.parse_slots(config["slots"], registry.env_params(parsed.name, parsed.args).n_agents)
        except ValueError as err:
            raise ValueError(f"the run's slots do not fit {spec}: {err}; choose them with --slots") from None
        slots = config["slots"]
    setup = playback.episode_setup(ckpt, spec, slots)
    decoder = network.DECODER_PARAMS[0] in setup.params and config.get("algo", "ppo") == "ppo"
    return setup, spec, decoder


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.render", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--env",
        help=f"NAME[:field=value,...], NAME one of: {', '.join(registry.registered_envs())} (default with "
        "--ckpt: the run's)",
    )
    parser.add_argument(
        "--out",
        help="output file, .gif or .mp4 (.mp4 needs imageio-ffmpeg); default with --ckpt: the run's own "
        "directory, RUN_DIR/learner.gif (RUN_DIR/learner-ENV.gif with --env), so no two runs' pictures "
        "collide",
    )
    parser.add_argument(
        "--ckpt", metavar="RUN_DIR", help="play the learner saved in this run (one seed's directory)"
    )
    parser.add_argument(
        "--slots", help="with --ckpt: one entry per agent, as in training (default: the run's)"
    )
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument(
        "--steps", type=int, default=None, help="at most this many steps (default: the env's max_steps)"
    )
    parser.add_argument("--fps", type=float, default=8.0, help="frames per second (default 8)")
    parser.add_argument("--tile", type=int, default=12, help="map pixels per cell (default 12)")
    parser.add_argument(
        "--scale",
        type=int,
        default=3,
        help="draw everything N times larger: N * --tile pixels per cell (default 3, legible at 100%%)",
    )
    parser.add_argument(
        "--policy",
        choices=POLICIES,
        help="without --ckpt: random: all 7 actions; random-move (default): turn or forward",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    args = parser.parse_args(argv)
    try:
        complete_args(args)
    except (ValueError, RuntimeError) as err:  # one line: the usage is for flags argparse cannot read
        raise SystemExit(f"{parser.prog}: error: {err}") from None
    return args


def complete_args(args: argparse.Namespace) -> None:
    """Check the parsed flags and complete them (the output path, the episode set-up), before JAX compiles
    anything; ValueError or RuntimeError says what is wrong."""
    if args.ckpt is None and args.env is None:
        raise ValueError("give --env (random actions) or --ckpt RUN_DIR (a trained learner)")
    if args.ckpt is None and args.slots is not None:
        raise ValueError("--slots needs --ckpt")
    if args.ckpt is not None and args.policy is not None:
        raise ValueError("--policy is for random actions; with --ckpt the saved policy acts")
    if args.out is None and args.ckpt is None:
        raise ValueError(
            "give --out FILE (.gif or .mp4): without --ckpt there is no run directory to write into"
        )
    if args.out is None:
        name = "learner.gif" if args.env is None else f"learner-{gif_name(args.env)}.gif"
        args.out = os.path.join(args.ckpt, name)
    if os.path.exists(args.out) and not args.overwrite:
        raise ValueError(f"{args.out} already exists; pass --overwrite to replace it")
    if args.steps is not None and args.steps < 1:
        raise ValueError(f"--steps {args.steps} must be >= 1")
    if args.fps <= 0:
        raise ValueError(f"--fps {args.fps} must be > 0")
    if args.tile < 3:
        raise ValueError(f"--tile {args.tile} must be >= 3")
    if args.scale < 1:
        raise ValueError(f"--scale {args.scale} must be an integer >= 1")
    args.tile *= args.scale
    check_video_path(args.out)
    if args.ckpt is None:
        spec = EnvSpec.parse(args.env)
        args.env_params = registry.env_params(spec.name, spec.args)
    else:
        args.setup, args.env, args.decoder = learner_setup(args.ckpt, args.env, args.slots)
        args.env_params = args.setup.env_params


def gif_name(env: str) -> str:
    """An environment spec as a file name part: 'goalcycle4:width=7' -> 'goalcycle4_width=7'."""
    return env.replace(":", "_").replace(",", "_")


def counted(n: int, one: str, many: str | None = None) -> str:
    """'1 reward', '2 rewards', '1 penalty', '0 penalties'."""
    return f"{n} {one if n == 1 else (many or one + 's')}"


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    env_params = args.env_params
    steps = env_params.max_steps if args.steps is None else args.steps
    if args.ckpt is None:
        episode = rollout_episode(jax.random.key(args.seed), env_params, args.policy or "random-move", steps)
        frames = episode_frames(episode, env_params, args.tile)
        rewards = np.array(episode["rewards"]).reshape(-1, env_params.n_agents)
        labels = ["random"] * env_params.n_agents
        terminated, truncated = episode["terminated"], episode["truncated"]
        print(f"env: {args.env} (seed {args.seed}, {args.policy or 'random-move'} policy)")
    else:
        episode = playback.play_episode(args.setup, steps, args.seed)
        predicted = playback.predicted_views(episode) if args.decoder else None
        title = DECODER_TITLES.get(args.setup.net_cfg.frame_aux, PREDICTED_TITLE)
        frames = playback.episode_video(episode, args.tile, predicted, title)
        rewards = episode["rewards"]
        labels = [s.label for s in args.setup.pop.slots]
        terminated, truncated = episode["terminated"][-1], episode["truncated"][-1]
        shown = "its decoder's output beside its view" if args.decoder else "no decoder output"
        print(f"run: {args.ckpt} (learner in slot {episode['learner']}, {shown})")
        print(f"env: {args.env} (seed {args.seed}, slots {','.join(labels)})")
    parent = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(parent, exist_ok=True)
    save_episode(frames, args.out, args.fps)

    ending = "all agents finished" if terminated.all() else ("time limit" if truncated else "step cap")
    print(f"steps: {len(rewards)} ({ending})")
    for i, label in enumerate(labels):
        print(
            f"agent {i} ({label}): return {rewards[:, i].sum():+.3f}, "
            f"{counted(int((rewards[:, i] > 0).sum()), 'reward')}, "
            f"{counted(int((rewards[:, i] < 0).sum()), 'penalty', 'penalties')}"
        )
    print(f"wrote {len(frames)} frames to {args.out}")
    if args.ckpt is None:
        print("next: watch a trained learner instead: --ckpt RUN_DIR (one seed's run directory)")
    else:
        print(f"next: its return over many episodes: python -m jaxsocial.evaluate --ckpt {args.ckpt} "
              f"--env {EnvSpec.parse(args.env)}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
