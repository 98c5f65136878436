"""Ship the visual-servoing runs at their validation-chosen models.

    python scripts/research/ship_selected.py --env cir_gym/VisualServoEyeToHand-v1 --agent ppo
        [--seeds 0 1 2 3] [--runs /work/main/runs/rl] [--selection results/visual_servo/agents]

For each finished run ``<runs>/<Env>/<agent>/seed_<k>``, reads its choice in
``<selection>/<Env>_selection.json`` (``eval_vs_agents.py select``: every checkpoint and the
final model on the validation seeds 8000–8029; the test seeds choose nothing) and ships that
model with :func:`cir_gym.agents.train.ship` into ``agents/trained/<Env>/<agent>/seed_<k>/``.
The shipped ``config.yml`` records ``selection``: the rule, the validation seeds, the command
that chooses again from a retrained run's models, and the chosen model's validation scores.
A run in training, or one whose saved models are not all in the selection, is refused: run
``select`` first.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_vs_agents import (
    CONTROLLERS,
    OUT,
    RUNS,
    VALIDATION_EPISODES,
    VALIDATION_SEED,
    candidates,
)

RULE = ("the highest success rate on the validation episodes, then the lowest final feature "
        "error IQM, then the fewest steps (eval_vs_agents.best)")


def select_command(env_id: str, agent: str) -> str:
    """The command that scores every saved model of the runs of ``agent`` on ``env_id`` and
    chooses."""
    return shlex.join(["python", "scripts/research/eval_vs_agents.py", "select", "--env",
                       env_id, "--algo", agent])


def choice(run: Path, record: dict[str, Any], name: str) -> dict[str, Any]:
    """The validation row chosen for ``run`` (its entry ``name``, ``<agent>/seed_<k>``, of the
    selection record); ValueError when the run is in training or has saved models the
    selection did not score."""
    command = select_command(record["env_id"], name.split("/")[0])
    entry = record["runs"].get(name)
    if entry is None or not entry["finished"]:
        raise ValueError(f"{name}: not a finished run in the selection; run "
                         f"`{command}` after it finishes")
    scored = {(r["source"], r["steps"]) for r in entry["rows"]}
    if missing := set(candidates(run)) - scored:
        raise ValueError(f"{name}: models not in the selection: {sorted(missing)}; run "
                         f"`{command}` first")
    chosen = entry["chosen"]
    return next(r for r in entry["rows"]
                if (r["source"], r["steps"]) == (chosen["source"], chosen["steps"]))


def ship_seed(env_id: str, agent: str, seed: int, runs: Path, record: dict[str, Any],
              record_file: Path) -> Path:
    """Ship seed ``seed`` of ``agent`` at its validation choice; return the agent directory."""
    from cir_gym.agents.train import ship

    name = f"{agent}/seed_{seed}"
    run = runs / env_id.split("/")[1] / agent / f"seed_{seed}"
    row = choice(run, record, name)
    selection = {
        "command": select_command(env_id, agent),
        "rule": RULE,
        "seeds": [record["seed"], record["seed"] + record["episodes"] - 1],
        "episodes": record["episodes"],
        "record": record_file.as_posix(),
        "success_rate": row["success_rate"],
        "final_feature_error_iqm_px": round(row["iqm"], 4),
    }
    steps = row["steps"] if row["source"] == "checkpoint" else None
    return ship(run, which=row["source"], steps=steps, selection=selection)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", required=True, choices=sorted(CONTROLLERS))
    ap.add_argument("--agent", required=True, help="run folder under <runs>/<Env>/, e.g. ppo")
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="training seeds (default: every finished run in the selection)")
    ap.add_argument("--runs", type=Path, default=RUNS)
    ap.add_argument("--selection", type=Path, default=OUT)
    args = ap.parse_args(argv)
    record_file = args.selection / f"{args.env.split('/')[1]}_selection.json"
    record = json.loads(record_file.read_text())
    if (record["seed"], record["episodes"]) != (VALIDATION_SEED, VALIDATION_EPISODES):
        raise SystemExit(f"{record_file}: seeds {record['seed']}… × {record['episodes']}, "
                         f"not the validation protocol's {VALIDATION_SEED}… × "
                         f"{VALIDATION_EPISODES}")
    seeds = args.seeds if args.seeds is not None else sorted(
        int(n.split("_")[-1]) for n, e in record["runs"].items()
        if n.startswith(f"{args.agent}/seed_") and e["finished"])
    for seed in seeds:
        try:
            target = ship_seed(args.env, args.agent, seed, args.runs, record, record_file)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        meta = json.loads((target / "meta.json").read_text())
        print(f"{target}: {meta['shipped_model']} at "
              f"{meta.get('shipped_steps', meta['timesteps'])} of {meta['timesteps']} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
