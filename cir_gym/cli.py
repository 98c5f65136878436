"""The ``cir-gym`` command line: a thin layer over the library (parse, call, print).

cir-gym list
cir-gym evaluate --env ID --policy NAME [--episodes N] [--seed S] [--set k=v ...]
                 [--plot out.png] [--video out.gif]
cir-gym leaderboard [--episodes N] [--out runs/leaderboard] [--env ID ...] [--no-videos]
cir-gym leaderboard --from DIR [--out DIR]    (a sweep's table: tables and figures)
cir-gym sweep GRID.yaml --out DIR [--workers N] [--ray ADDRESS|auto|local] [--retries N]
cir-gym train ...      (see ``cir_gym.agents.train``)
cir-gym export-zoo --env ID --agent NAME [--out logs]   (rl-zoo3's layout, ``cir_gym.agents.zoo``)
cir-gym identify ...   (see ``cir_gym.scoring.identify``)
"""

from __future__ import annotations

import argparse
import importlib.metadata
import sys
from pathlib import Path
from typing import Any

import cir_gym
from cir_gym.agents.hyperparameters import ALGORITHMS
from cir_gym.envs.base import make_env
from cir_gym.evaluation import evaluate, interface_env_kwargs
from cir_gym.scoring.policies import (
    ENTRY_POINT_GROUP,
    TRAIN_EXTRA,
    PolicyError,
    check_env_id,
    check_env_kwargs,
    check_policy,
    make_policy,
    module_missing,
    parse_value,
    plugin_factories,
    policy_names,
    resolve_tuned,
    shipped_agents,
    split_settings,
    train_extra_missing,
)
from cir_gym.scoring.tables import format_table


class CliError(Exception):
    """A user error: printed without a traceback, exit status 2."""


PLOT_SUFFIXES = (".png", ".pdf", ".svg")
VIDEO_SUFFIXES = (".mp4", ".gif")
PLOTS_EXTRA = "pip install 'cir-gym[plots]'"
#: the main job's output folder (untracked; ``--out results/`` regenerates the repository's)
LEADERBOARD_OUT = "runs/leaderboard"


def version() -> str:
    """The installed distribution's version (``cir-gym --version``)."""
    try:
        return importlib.metadata.version("cir-gym")
    except importlib.metadata.PackageNotFoundError:  # run from a source tree, not installed
        return "unknown (not installed)"


def _need(option: str, modules: tuple[str, ...]) -> None:
    """Fail before any work when ``option``'s writer needs a module that is not installed."""
    missing = [m for m in modules if module_missing(m)]
    if missing:
        raise CliError(f"{option} needs {', '.join(missing)}: {PLOTS_EXTRA}")


def _check_suffix(option: str, path: str | None, allowed: tuple[str, ...]) -> None:
    """Reject an output path whose extension the writer does not support (before any work)."""
    if path is not None and Path(path).suffix.lower() not in allowed:
        raise CliError(
            f"{option} {path!r}: unsupported extension {Path(path).suffix or '(none)'!r}; "
            f"allowed: {', '.join(allowed)}"
        )


# ---------------------------------------------------------------------- commands
def cmd_list(args: argparse.Namespace) -> int:
    agents_off = bool(train_extra_missing())
    for env_id, (_, description) in cir_gym.ENVIRONMENTS.items():
        print(f"{env_id}\n    {description}\n    policies: {', '.join(policy_names(env_id))}")
        if agents_off and shipped_agents(env_id):
            print(f"    trained agents (need the train extra): "
                  f"{', '.join(shipped_agents(env_id))}")
    if agents_off:
        print(f"\nTrained agents need the train extra: {TRAIN_EXTRA}")
    plugins = sorted(plugin_factories())
    print(
        f"\nPlugin policies ({ENTRY_POINT_GROUP} entry points): "
        + (", ".join(f"{p} ({plugin_factories()[p].value})" for p in plugins)
           or "none installed (docs/policies.md: how to add your own)")
    )
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    env_id = check_env_id(args.env)
    _check_suffix("--plot", args.plot, PLOT_SUFFIXES)
    _check_suffix("--video", args.video, VIDEO_SUFFIXES)
    if args.plot:
        _need("--plot", ("matplotlib",))
    if args.video:
        _need("--video", ("imageio",))
    if args.episodes < 1:
        raise CliError(f"--episodes must be >= 1, got {args.episodes}")
    check_policy(env_id, args.policy)
    env_kwargs, gains = split_settings(env_id, args.policy, args.set or [])
    check_env_kwargs(env_id, env_kwargs)
    policy = make_policy(env_id, args.policy, env_kwargs, gains)
    try:
        result = evaluate(
            policy,
            env_id,
            args.episodes,
            args.seed,
            record=bool(args.plot),
            policy_name=args.policy,
            **env_kwargs,
        )
    except (ValueError, TypeError) as exc:  # bad environment argument, wrong action shape
        raise CliError(str(exc)) from exc
    print(format_table([result], markdown=False))
    try:
        if args.plot:
            from cir_gym.scoring.plotting import plot_episode

            print(f"plot: {plot_episode(result, args.plot)}")
        if args.video:
            try:
                video = record_video(policy, env_id, args.video, args.seed, env_kwargs)
            except RuntimeError as exc:  # no OpenGL context (headless: MUJOCO_GL=egl), no MP4
                raise CliError(f"cannot write the video {args.video}: {exc}") from exc
            print(f"video: {video}")
    except ImportError as exc:  # the plots extra (matplotlib, imageio) is not installed
        raise CliError(str(exc)) from exc
    return 0


def record_video(
    policy: Any, env_id: str, path: str, seed: int, env_kwargs: dict[str, Any], size: int = 320
) -> Path:
    """One episode rendered with ``rgb_array`` frames at ≤ 25 fps."""
    from cir_gym.scoring.plotting import save_video

    env_kwargs = interface_env_kwargs(policy, env_kwargs)
    env = make_env(env_id, render_mode="rgb_array", width=size, height=size, **env_kwargs)
    every = max(1, round(1.0 / (25 * env.unwrapped.dt)))
    frames = []
    obs, _ = env.reset(seed=seed)
    state, start, done, k = None, True, False, 0
    while not done:
        if k % every == 0:
            frames.append(env.render())
        action, state = policy.predict(obs, state=state, episode_start=[start], deterministic=True)
        start = False
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
        k += 1
    env.close()
    return save_video(frames, path, fps=round(1.0 / (every * env.unwrapped.dt)))


def cmd_leaderboard(args: argparse.Namespace) -> int:
    from cir_gym.scoring.leaderboard import FAILED_HEADING, run_leaderboard

    if args.from_dir is not None:
        from cir_gym.scoring.leaderboard import leaderboard_from

        try:
            md = leaderboard_from(Path(args.from_dir), Path(args.out) if args.out else None)
        except FileNotFoundError as exc:  # no sweep table in DIR
            raise CliError(str(exc)) from exc
        print(f"page: {(md.parent / 'index.html').resolve()}\ntables: {md.resolve()}",
              file=sys.stderr)
        return 0
    if args.episodes < 1:
        raise CliError(f"--episodes must be >= 1, got {args.episodes}")
    md = run_leaderboard(
        Path(args.out or LEADERBOARD_OUT),
        episodes=args.episodes,
        seed=args.seed,
        envs=[check_env_id(e) for e in args.env] if args.env else None,
        videos=not args.no_videos,
    )
    return 1 if md is not None and FAILED_HEADING in md.read_text() else 0


def _need_train_extra(what: str) -> None:
    if train_extra_missing():
        raise CliError(
            f"{what} needs the train extra (missing: {', '.join(train_extra_missing())}): "
            f"{TRAIN_EXTRA}"
        )


def cmd_train(args: argparse.Namespace) -> int:
    _need_train_extra("training")
    try:
        from cir_gym.agents.train import train
    except ImportError as exc:
        raise CliError(
            f"training needs the train extra: pip install 'cir-gym[train]' ({exc})"
        ) from exc
    env_id = check_env_id(args.env)
    env_kwargs, gains = split_settings(env_id, args.residual or "", args.set or [])
    residual, gains = resolve_tuned(env_id, args.residual or "", env_kwargs, gains)
    try:
        train(
            env_id,
            args.algo,
            timesteps=args.timesteps,
            seed=args.seed,
            residual=residual or None,
            residual_gains=gains or None,
            resume=args.resume,
            out=args.out,
            name=args.name,
            env_kwargs=env_kwargs,
            n_envs=args.n_envs,
            residual_scale=parse_value(args.residual_scale)
            if args.residual_scale is not None else None,
            hyperparams_path=args.hyperparams,
        )
    except ValueError as exc:  # bad residual controller, existing run without --resume, ...
        raise CliError(str(exc)) from exc
    return 0


def cmd_export_zoo(args: argparse.Namespace) -> int:
    _need_train_extra("export-zoo")
    from cir_gym.agents.zoo import enjoy_command, export_zoo, record_video_command

    env_id = check_env_id(args.env)
    agent = args.agent.removeprefix("agent:")
    try:
        run = export_zoo(env_id, agent, args.out, seed=args.seed, exp_id=args.exp_id)
    except ValueError as exc:  # unknown agent, existing experiment folder, ...
        raise CliError(str(exc)) from exc
    print(f"wrote {run}\nrun it:   {enjoy_command(run)}\n"
          f"video:    {record_video_command(run, Path(args.out) / 'videos')}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from cir_gym.scoring.sweep import GridError, RayUnavailable, run_sweep

    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be >= 1, got {args.workers}")
    if args.retries < 0:
        raise CliError(f"--retries must be >= 0, got {args.retries}")
    try:
        summary = run_sweep(
            args.grid, args.out, workers=args.workers, ray=args.ray, retries=args.retries
        )
    except (GridError, RayUnavailable) as exc:
        raise CliError(str(exc)) from exc
    except ImportError as exc:  # --ray without the sweep extra
        raise CliError(str(exc)) from exc
    print(
        f"{summary.tasks} tasks: {summary.skipped} already finished, {summary.ran} run "
        f"({summary.failed} failed) in {summary.seconds:.1f} s; table {summary.table}"
    )
    return 1 if summary.failed else 0


def cmd_identify(args: argparse.Namespace) -> int:
    from cir_gym.scoring.identify import run_identify

    run_identify(
        payload_mass=args.payload_mass,
        duration=args.duration,
        noise=args.noise,
        seed=args.seed,
        episodes=args.episodes,
    )
    return 0


#: the main job's episodes per (variant, policy): a first look that keeps ``bash scripts/run.sh``
#: within 15 minutes on 2 free cores (299 runs and 22 agents' seed tables; quoted numbers need
#: ``--episodes 30`` and take about 10 times as long)
LEADERBOARD_EPISODES = 3


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cir-gym", description=__doc__.split("\n")[0])
    p.add_argument("--version", action="version", version=f"cir-gym {version()}")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="environments and their policies").set_defaults(func=cmd_list)

    e = sub.add_parser(
        "evaluate",
        help="score one policy on one environment",
        description="Score one policy on one environment: episodes on seeds SEED, SEED+1, ...; "
        "prints the metrics' mean, worst episode and CVaR.",
    )
    e.add_argument(
        "--env",
        required=True,
        metavar="ID",
        help="environment id, e.g. cir_gym/JointTracking-v2 or JointTracking-v2 (cir-gym list)",
    )
    e.add_argument(
        "--policy",
        required=True,
        metavar="NAME",
        help="a controller (computed_torque), tuned:<controller>, agent:<name> (train extra) "
        "or plugin:<name> (cir-gym list names them per environment)",
    )
    e.add_argument("--episodes", type=int, default=5,
                   help="number of episodes (default: %(default)s)")
    e.add_argument("--seed", type=int, default=0,
                   help="seed of the first episode (default: %(default)s)")
    e.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        default=None,
        help="environment argument (payload_mass=3.0) or controller gain (omega_n=40), a "
        "Python literal; repeatable (default: the environment's and controller's defaults)",
    )
    e.add_argument(
        "--plot",
        metavar="OUT.png",
        default=None,
        help=f"plot of episode 0 ({', '.join(PLOT_SUFFIXES)}; plots extra; default: none)",
    )
    e.add_argument(
        "--video",
        metavar="OUT.gif",
        default=None,
        help=f"video of episode 0 ({', '.join(VIDEO_SUFFIXES)}; plots extra; default: none)",
    )
    e.set_defaults(func=cmd_evaluate)

    lb = sub.add_parser(
        "leaderboard",
        help="every policy on every environment (the main job)",
        description="Every policy on every environment's variants, on the same seeds: ranked "
        "tables (leaderboard.md), figures, a video per variant and a page (index.html) in "
        f"--out (default {LEADERBOARD_OUT}, untracked; --out results/ regenerates the "
        "repository's). The time is estimated at the start and shown as it runs.",
    )
    lb.add_argument("--episodes", type=int, default=LEADERBOARD_EPISODES,
                    help="episodes per (variant, policy) (default: %(default)s)")
    lb.add_argument("--seed", type=int, default=1000,
                    help="seed of the first episode (default: %(default)s)")
    lb.add_argument(
        "--out",
        default=None,
        help=f"output folder (default: {LEADERBOARD_OUT}, or DIR with --from)",
    )
    lb.add_argument("--env", action="append", metavar="ID",
                    help="only these environments (repeatable; default: all)")
    lb.add_argument("--no-videos", action="store_true", help="leave the page's videos out")
    lb.add_argument(
        "--from",
        dest="from_dir",
        metavar="DIR",
        default=None,
        help="render a sweep's table (cir-gym sweep --out DIR) instead of running",
    )
    lb.set_defaults(func=cmd_leaderboard)

    sw = sub.add_parser(
        "sweep",
        help="a grid (YAML) of evaluations and training runs as "
        "independent tasks, on a local pool or Ray",
    )
    sw.add_argument("grid", metavar="GRID", help="grid file (docs/sweeps.md; examples in sweeps/)")
    sw.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="results: tasks/*.json, results.parquet (or .csv), runs/",
    )
    sw.add_argument(
        "--workers",
        type=int,
        default=None,
        help="local processes (default: one per core); CPUs with --ray local",
    )
    sw.add_argument(
        "--ray",
        metavar="ADDRESS",
        default=None,
        help="run on Ray: a cluster address, 'auto' (the cluster running here, started with "
        "`ray start --head`) or 'local' (start one for this sweep); needs the sweep extra. "
        "On one machine the local pool (the default) is as fast",
    )
    sw.add_argument(
        "--retries",
        type=int,
        default=2,
        help="retries of a task that raised or whose worker died (default 2)",
    )
    sw.set_defaults(func=cmd_sweep)

    t = sub.add_parser("train", help="train an SB3 agent (needs the train extra)")
    t.add_argument("--env", required=True)
    t.add_argument("--algo", choices=ALGORITHMS, default="ppo")
    t.add_argument(
        "--residual",
        metavar="CONTROLLER",
        help="train a residual on this controller; tuned:<controller> takes the gains tuned for "
        "these --set environment arguments (cir_gym/scoring/tuned_gains/); --set "
        "<gain>=<value> sets a gain",
    )
    t.add_argument("--residual-scale", metavar="SCALE", default=None,
                   help="the residual's range per action component, a number or a list "
                   "([0.1, 0.1, ...]); default: the hyperparameter entry's residual.scale")
    t.add_argument("--timesteps", type=int, default=None,
                   help="environment steps in total (default: the entry's n_timesteps)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--n-envs", type=int, default=None)
    t.add_argument("--resume", action="store_true",
                   help="continue <out>/<Env>/<name> from its last checkpoint up to --timesteps")
    t.add_argument("--name", default=None, help="run name (default <algo> or "
                   "residual_<algo>_<controller>; <agent>/seed_<k> for one seed of an agent)")
    t.add_argument("--out", default="runs", help="root of the run folders (default: runs)")
    t.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="an environment argument or a gain of the --residual controller")
    t.add_argument(
        "--hyperparams",
        metavar="YAML",
        default=None,
        help="hyperparameter file instead of agents/hyperparams/<algo>.yml "
        "(e.g. agents/hyperparams/levers/rik_*.yml)",
    )
    t.set_defaults(func=cmd_train)

    z = sub.add_parser(
        "export-zoo",
        help="write a shipped agent in rl-zoo3's folder layout (rl_zoo3.enjoy, record_video)",
    )
    z.add_argument("--env", required=True, help="the id it runs on, e.g. cir_gym/JointTracking-v2")
    z.add_argument("--agent", required=True, metavar="NAME",
                   help="a shipped agent (agent:<name> or <name>; cir-gym list shows them)")
    z.add_argument("--seed", type=int, default=None, help="training seed (default: the first)")
    z.add_argument("--out", default="logs", help="rl-zoo3's log folder, -f (default: logs)")
    z.add_argument("--exp-id", type=int, default=None,
                   help="rl-zoo3's experiment id (default: the next free one)")
    z.set_defaults(func=cmd_export_zoo)

    i = sub.add_parser("identify", help="least-squares identification, then computed torque")
    i.add_argument("--payload-mass", type=float, default=3.0)
    i.add_argument("--duration", type=float, default=60.0, help="excitation length (s)")
    i.add_argument("--noise", type=float, default=0.2, help="torque noise std (N m)")
    i.add_argument("--episodes", type=int, default=5)
    i.add_argument("--seed", type=int, default=0)
    i.set_defaults(func=cmd_identify)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (CliError, PolicyError) as exc:
        print(f"cir-gym: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cir-gym: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
