"""Score the visual-servoing agents of ``scripts/research/train_vs.sh`` against tuned IBVS.

    python scripts/research/eval_vs_agents.py select [--env cir_gym/VisualServo-v1]
        [--algo AGENT ...] [--runs /work/main/runs/rl] [--out results/visual_servo/agents]
    python scripts/research/eval_vs_agents.py evaluate [--env cir_gym/VisualServo-v1]
        [--episodes 100] [--algo AGENT ...] [--runs /work/main/runs/rl]
        [--out results/visual_servo/agents]
    python scripts/research/eval_vs_agents.py rotation [--episodes 30] [...]
    python scripts/research/eval_vs_agents.py bench [--steps 1000]

``select``: checkpoint selection on validation episodes. Every run ``<runs>/<Env>/<algo>/seed_<k>``
has its checkpoints ``checkpoints/model_<N>_steps.zip`` (each with its own VecNormalize
statistics) and, once finished, its final ``model.zip``; each of them is scored on the
``VALIDATION_EPISODES`` episodes ``VALIDATION_SEED …`` (seeds no training, evaluation during
training, study, test, tuning, leaderboard or other measurement uses), and the run's choice is
the one of the highest success rate, then the lowest final feature error IQM, then the fewest
steps. SB3's ``best/`` (EvalCallback's mean return of 5 episodes) is not a candidate: the return
ranks models differently from the success rate and final error this evaluation reports. Writes
``<out>/<Env>_selection.json`` (per run: the choice and every candidate's episodes; a candidate
already there with the same seeds and episode count is not scored again) and ``.md``.

``evaluate``: brings the selection up to date (``select``, cached), then scores per run two
models — its final model (else its last checkpoint, labelled with its step count and "in
training") and its validation choice (labelled "validation choice") — and the env's controllers
— tuned IBVS (``tuned:ibvs``, cir_gym/scoring/tuned_gains/), the course gains — on the held-out
episodes ``TEST_SEED …`` (seeds no training, evaluation during training, validation, study,
tuning or leaderboard run uses), by :func:`cir_gym.evaluation.evaluate`. The test seeds choose
nothing: the validation choice is fixed before they run, the final model needs no choice, and
both rows are reported (taking the better one per run would be a choice on the test seeds). The
validation choices are the agent this protocol delivers; the final models show what the choice
changes. Per policy: success with its Wilson 95 % interval, the final feature error's IQM with a
95 % bootstrap interval (:func:`cir_gym.agents.report.interval`, rliable's stratified bootstrap:
over the training seeds × episodes matrix when an algorithm has ≥ 2 seeds, over the episodes for
one run or a controller), and its ratio to tuned IBVS's IQM; per algorithm, the same over its
seeds' final models and over their validation choices. Writes ``<out>/<Env>.md`` and
``<out>/<Env>.json`` (every episode's final error and outcome; a policy already there with the
same label, seeds and episode count is not run again, nor a model already scored under another
label, so re-running after more training evaluates only the new models).

``rotation``: the rotation family of ``eval_visual_servo.py`` (start_offset (0, 0, 0, 0, 0, θ),
the default 0.1 px feature noise, seeds ``ROTATION_SEED …``) for the eye-in-hand agents beside
IBVS (tuned and course gains, and the mean-L law) and PBVS; the convergence region of a policy
is the largest θ up to which every angle of the list succeeds in ≥ 90 % of the episodes.
Writes ``<out>/rotation.md``.

``bench``: CPU cost of the off-policy learners on VisualServo-v1 — SB3's SAC, sb3-contrib's
TQC and CrossQ, beside PPO — with ``bench_offpolicy.py``'s settings (one gradient step of batch
256 per env step, 256×256 networks, one torch thread, ``time.process_time``), on this env.
Writes ``<out>/offpolicy_bench.md``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cir_gym.metrics import wilson_interval

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_visual_servo import ROTATION_SEED

EYE_IN_HAND = "cir_gym/VisualServo-v1"
EYE_TO_HAND = "cir_gym/VisualServoEyeToHand-v1"
TEST_SEED = 7000  # held-out: no training (0…, 100_000…), study (60_000…) or other measurement
#: checkpoint selection: seeds 8000–8029, which no training (0…), evaluation during training
#: (100_000…), study (60_000…), test (7000–7099), leaderboard (1000…), agent (2000…), rotation
#: (3000…) or contact (5000…) run uses
VALIDATION_SEED = 8000
VALIDATION_EPISODES = 30
RUNS = Path("/work/main/runs/rl")
OUT = Path("results/visual_servo/agents")
#: the controllers scored beside the agents: (label, controller name, tuned)
CONTROLLERS = {
    EYE_IN_HAND: (("tuned:ibvs", "ibvs", True), ("ibvs", "ibvs", False),
                  ("pbvs", "pbvs", False)),
    EYE_TO_HAND: (("tuned:ibvs_eye_to_hand", "ibvs_eye_to_hand", True),
                  ("ibvs_eye_to_hand", "ibvs_eye_to_hand", False)),
}
ROTATION_ANGLES = (60.0, 75.0, 90.0, 120.0, 150.0, 170.0, 180.0)  # deg
REGION_SUCCESS = 0.9  # a rotation inside a policy's convergence region: ≥ 90 % success


def controller(env_id: str, name: str, tuned: bool, env_kwargs: dict[str, Any] | None = None,
               **gains: Any) -> Any:
    """A course controller at its course gains, or at the gains tuned for the projected-
    features variant (``tuned``)."""
    from cir_gym import baselines
    from cir_gym.scoring.policies import tuned_gains

    if tuned:
        gains = {**tuned_gains(env_id, name, {}), **gains}
    return baselines.make(name, env_id, env_kwargs=env_kwargs or {}, **gains)


def runs_of(root: Path, env_id: str, algos: list[str] | None = None) -> list[Path]:
    """The run directories ``<root>/<Env>/<algo>/seed_<k>`` that hold a config, of the agents
    ``algos`` only when given (``--algo``; ValueError naming the agents there when one of them
    has no run)."""
    base = root / env_id.split("/")[1]
    runs = sorted(p.parent for p in base.glob("*/seed_*/config.yml"))
    found = {r.parent.name for r in runs}
    if unknown := sorted(set(algos or ()) - found):
        raise ValueError(f"--algo {', '.join(unknown)}: no run under {base}; agents there: "
                         f"{', '.join(sorted(found)) or 'none'}")
    return [r for r in runs if algos is None or r.parent.name in algos]


def other_agents(entries: dict[str, Any], algos: list[str] | None,
                 agent_of: Callable[[str, Any], str]) -> dict[str, Any]:
    """The entries of agents a call restricted to ``algos`` does not score, kept as an earlier
    call left them (none when every agent is scored)."""
    if algos is None:
        return {}
    return {k: v for k, v in entries.items() if agent_of(k, v) not in algos}


def algo_option(algos: list[str] | None) -> str:
    """The ``--algo`` options of a command line that chose ``algos`` ("" for every run)."""
    return "".join(f" --algo {a}" for a in algos or [])


def checkpoint_steps(run: Path) -> list[int]:
    """The step counts of a run's saved checkpoints (``checkpoints/model_<N>_steps.zip`` with
    its ``model_vecnormalize_<N>_steps.pkl``, written after it), ascending."""
    folder = run / "checkpoints"
    return sorted(int(m.group(1)) for f in folder.glob("model_*_steps.zip")
                  if (m := re.fullmatch(r"model_(\d+)_steps\.zip", f.name))
                  and (folder / f"model_vecnormalize_{m.group(1)}_steps.pkl").exists())


def finished_steps(run: Path) -> int | None:
    """The step count of a run's final ``model.zip`` (``meta.json``), None while in training."""
    meta = run / "meta.json"
    if meta.exists() and (m := json.loads(meta.read_text())).get("finished"):
        return int(m["timesteps"])
    return None


def checkpoint_agent(run: Path, root: Path, steps: int) -> Path:
    """Checkpoint ``steps`` of ``run`` as an agent directory ``<root>/snapshots/<run>/step_<N>``
    for :func:`cir_gym.agents.policy.load_agent`: the run's config, the checkpoint's model.zip
    and its VecNormalize statistics as normalization.npz
    (:func:`cir_gym.agents.train.write_normalization`, the one writer of that file)."""
    dest = root / "snapshots" / run.relative_to(root) / f"step_{steps}"
    if not (dest / "normalization.npz").exists():
        import pickle

        from cir_gym.agents.train import write_normalization

        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy2(run / "config.yml", dest / "config.yml")
        shutil.copy2(run / "checkpoints" / f"model_{steps}_steps.zip", dest / "model.zip")
        with (run / "checkpoints" / f"model_vecnormalize_{steps}_steps.pkl").open("rb") as f:
            vn = pickle.load(f)  # our own training's checkpoint: a trusted pickle
        write_normalization(vn, dest)
    return dest


def checkpoint_policy(run: Path, root: Path, steps: int | None, env_id: str) -> tuple[int, Any]:
    """(steps, agent) of checkpoint ``steps`` (None: the last) of the run folder ``run`` under
    ``root``, loaded by :func:`cir_gym.agents.policy.load_agent` on ``env_id``.

    Raises:
        ValueError: no checkpoint, or none at ``steps`` (the message lists the saved ones).
    """
    from cir_gym.agents.policy import load_agent

    saved = checkpoint_steps(run)
    if not saved:
        raise ValueError(f"{run} has no checkpoint (checkpoints/model_<N>_steps.zip)")
    steps = max(saved) if steps is None else steps
    if steps not in saved:
        raise ValueError(f"--steps {steps}: {run} has checkpoints at {saved}")
    return steps, load_agent(checkpoint_agent(run, root, steps), env_id)


def agent_of(run: Path, root: Path, source: str, steps: int) -> Path:
    """The agent directory of a run's ``"final"`` model (the run itself) or of its
    ``"checkpoint"`` at ``steps``."""
    if source == "final":
        return run
    if source == "checkpoint":
        return checkpoint_agent(run, root, steps)
    raise ValueError(f"source must be 'final' or 'checkpoint', got {source!r}")


def snapshot(run: Path, root: Path) -> tuple[Path, int, bool]:
    """(agent directory, steps, finished) of a run: the run itself when it finished, else its
    last checkpoint (:func:`checkpoint_agent`)."""
    if (done := finished_steps(run)) is not None:
        return run, done, True
    steps = checkpoint_steps(run)
    if not steps:
        raise FileNotFoundError(f"{run}: no checkpoint yet")
    return checkpoint_agent(run, root, steps[-1]), steps[-1], False


def outcomes(res: Any) -> dict[str, list]:
    eps = res.episodes
    return {"final_feature_error": [float(e.metrics["final_feature_error"]) for e in eps],
            "success": [bool(e.success) for e in eps],
            "terminated": [bool(e.terminated) for e in eps],
            "convergence_time": [float(e.metrics["convergence_time"]) for e in eps]}


def row(label: str, finals: np.ndarray, success: np.ndarray, ended: int, t_conv: float,
        reference: float | None) -> str:
    """One table row; ``finals`` and ``success`` (runs × episodes)."""
    from cir_gym.agents.report import interval

    x = finals if finals.shape[0] > 1 else finals.T  # one run: bootstrap the episodes
    point, lo, hi = interval(x)
    wins, n = int(success.sum()), success.size
    low, high = wilson_interval(wins, n)
    ratio = f"{point / reference:.2f}" if reference else "–"
    return (f"| {label} | {wins}/{n} = {100 * wins / n:.1f} % ({100 * low:.1f}–{100 * high:.1f}) "
            f"| {point:.3f} ({lo:.3f}–{hi:.3f}) | {ratio} | {np.median(finals):.3f} | {ended} "
            f"| {t_conv:.2f} |")


#: a run's candidate model: ("checkpoint", N) for checkpoints/model_<N>_steps.zip, ("final",
#: N) for the finished run's model.zip after N steps
Candidate = tuple[str, int]
#: scores one candidate of a run on the validation episodes → :func:`outcomes`' lists
Scorer = Callable[[Path, str, int], dict[str, list]]


def candidates(run: Path) -> list[Candidate]:
    """Every saved model of a run: its checkpoints by step count, then its final model."""
    found: list[Candidate] = [("checkpoint", k) for k in checkpoint_steps(run)]
    if (done := finished_steps(run)) is not None:
        found.append(("final", done))
    return found


def validation_row(source: str, steps: int, episodes: dict[str, list], cpu_s: float
                   ) -> dict[str, Any]:
    """One candidate's validation record: its episodes' outcomes, success rate (0–1) and the
    final feature error's IQM (px) over the episodes, and the CPU seconds its scoring took."""
    from cir_gym.agents.report import iqm

    return {"source": source, "steps": steps,
            "success_rate": float(np.mean(episodes["success"])),
            "iqm": iqm(np.array(episodes["final_feature_error"])),
            "cpu_s": round(cpu_s, 1), **episodes}


def best(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The validation choice: the highest success rate, then the lowest final-error IQM, then
    the fewest steps."""
    if not rows:
        raise ValueError("best: no candidate rows to choose from")
    return min(rows, key=lambda r: (-r["success_rate"], r["iqm"], r["steps"]))


def validation_scorer(env_id: str, root: Path, episodes: int) -> Scorer:
    """A run's candidate on seeds ``VALIDATION_SEED …`` with the run's own normalisation
    (:func:`agent_of`, :func:`cir_gym.agents.policy.load_agent`), deterministic actions."""
    def score(run: Path, source: str, steps: int) -> dict[str, list]:
        from cir_gym.agents.policy import load_agent

        from cir_gym.evaluation import evaluate

        agent = load_agent(agent_of(run, root, source, steps), env_id)
        return outcomes(evaluate(agent, env_id, episodes, VALIDATION_SEED,
                                 policy_name=f"{run.name} {source} {steps}"))
    return score


def select_env(env_id: str, root: Path, out: Path, episodes: int = VALIDATION_EPISODES,
               score: Scorer | None = None, algos: list[str] | None = None) -> dict[str, Any]:
    """Score every candidate (:func:`candidates`) of every run of ``env_id`` on the validation
    episodes, choose one per run (:func:`best`), write ``<out>/<Env>_selection.json`` (and a
    table, ``.md``) and return that record. A candidate already in the file with the same
    seeds and episode count is not scored again. ``algos``: only these agents' runs are
    scored; the other agents' entries stay as an earlier call left them."""
    score = score or validation_scorer(env_id, root, episodes)
    file = out / f"{env_id.split('/')[1]}_selection.json"
    earlier: dict[str, Any] = {}
    if file.exists():
        old = json.loads(file.read_text())
        if (old["seed"], old["episodes"]) == (VALIDATION_SEED, episodes):
            earlier = old["runs"]
    runs: dict[str, Any] = {}
    for run in runs_of(root, env_id, algos):
        name = f"{run.parent.name}/{run.name}"
        known = {(r["source"], r["steps"]): r for r in earlier.get(name, {}).get("rows", [])}
        rows = []
        for source, steps in candidates(run):
            if (source, steps) not in known:
                t0 = time.process_time()
                episodes_of = score(run, source, steps)
                known[source, steps] = validation_row(source, steps, episodes_of,
                                                      time.process_time() - t0)
                print(f"{name} {source} {steps}: {known[source, steps]['success_rate']:.2f}, "
                      f"IQM {known[source, steps]['iqm']:.3f} px", flush=True)
            rows.append(known[source, steps])
        if not rows:
            print(f"{run}: no checkpoint yet", flush=True)
            continue
        choice = best(rows)
        runs[name] = {"finished": finished_steps(run) is not None,
                      "chosen": {"source": choice["source"], "steps": choice["steps"]},
                      "rows": rows}
        out.mkdir(parents=True, exist_ok=True)  # after every run: an interruption keeps it
        file.write_text(json.dumps({"env_id": env_id, "seed": VALIDATION_SEED,
                                    "episodes": episodes, "runs": {**earlier, **runs}},
                                   indent=1))
    kept = other_agents(earlier, algos, lambda name, _: name.split("/")[0])
    record = {"env_id": env_id, "seed": VALIDATION_SEED, "episodes": episodes,
              "runs": {**kept, **runs}, "algos": algos}
    out.mkdir(parents=True, exist_ok=True)
    file.write_text(json.dumps(record, indent=1))
    file.with_suffix(".md").write_text(selection_markdown(record))
    return record


def selection_markdown(record: dict[str, Any]) -> str:
    """Per run, every candidate's validation success and final-error IQM, the chosen marked."""
    env_id, seed, n = record["env_id"], record["seed"], record["episodes"]
    lines = [f"# Checkpoint selection on {env_id.split('/')[1]}", "",
             f"Written by `python scripts/research/eval_vs_agents.py select --env {env_id}"
             f"{algo_option(record.get('algos'))}`: "
             f"every saved checkpoint and final model of every run on the validation seeds "
             f"{seed}–{seed + n - 1} (not the test seeds {TEST_SEED}…), with the run's own "
             "observation statistics, deterministic actions. Chosen (**bold**): the highest "
             "success rate, then the lowest final-error IQM, then the fewest steps."
             + (" Other agents' runs as their last selection left them."
                if record.get("algos") else ""), ""]
    for name, r in record["runs"].items():
        lines += [f"## {name}" + ("" if r["finished"] else " (in training)"), "",
                  "| model | steps | success | final error IQM (px) | median (px) "
                  "| ended early |", "|---|---:|---:|---:|---:|---:|"]
        for v in r["rows"]:
            chosen = (v["source"], v["steps"]) == (r["chosen"]["source"], r["chosen"]["steps"])
            mark = "**" if chosen else ""
            lines.append(f"| {mark}{v['source']}{mark} | {v['steps']} "
                         f"| {sum(v['success'])}/{len(v['success'])} | {v['iqm']:.3f} "
                         f"| {np.median(v['final_feature_error']):.3f} "
                         f"| {sum(v['terminated'])} |")
        lines.append("")
    return "\n".join(lines)


def model_of(record: dict[str, Any]) -> tuple[str, str, int]:
    """(run, source, steps) of an agent's test record; records written before the validation
    selection have no ``source``: a finished run's was its final model, else a checkpoint."""
    source = record.get("source", "final" if record["finished"] else "checkpoint")
    return record["run"], source, int(record["steps"])


def policies_of(run: Path, chosen: dict[str, Any] | None) -> list[tuple[str, str, str, int]]:
    """(label, selection, source, steps) of the models of ``run`` scored on the test seeds:
    its final model (its last checkpoint while in training; selection ``"final"``) and its
    validation choice ``chosen`` (selection ``"validation"``; none before any checkpoint)."""
    who = f"{run.parent.name} {run.name.replace('_', ' ')}"
    if (done := finished_steps(run)) is not None:
        found = [(f"{who} @ {done / 1e6:.2f} M steps", "final", "final", done)]
        training = ""
    elif steps := checkpoint_steps(run):
        training = " (in training)"
        found = [(f"{who} @ {steps[-1] / 1e6:.2f} M steps{training}", "final", "checkpoint",
                  steps[-1])]
    else:
        print(f"{run}: no checkpoint yet", flush=True)
        return []
    if chosen is not None:
        what = "final model" if chosen["source"] == "final" else "checkpoint"
        found.append((f"{who} @ {chosen['steps'] / 1e6:.2f} M steps (validation choice: "
                      f"{what}){training}", "validation", chosen["source"], chosen["steps"]))
    return found


def evaluate_env(env_id: str, episodes: int, root: Path, out: Path,
                 algos: list[str] | None = None) -> Path:
    from cir_gym.agents.policy import load_agent

    from cir_gym.evaluation import evaluate

    stem = out / env_id.split("/")[1]
    earlier: dict[str, dict[str, Any]] = {}  # the last call's episodes, reused when unchanged
    if stem.with_suffix(".json").exists():
        old = json.loads(stem.with_suffix(".json").read_text())
        if (old["seed"], old["episodes"]) == (TEST_SEED, episodes):
            earlier = old["results"]
    results: dict[str, dict[str, Any]] = {}
    for label, name, tuned in CONTROLLERS[env_id]:
        if label not in earlier:
            res = evaluate(controller(env_id, name, tuned), env_id, episodes, TEST_SEED,
                           policy_name=label)
            earlier[label] = {"kind": "controller", **outcomes(res)}
        results[label] = earlier[label]
        print(label, np.mean(results[label]["success"]), flush=True)
    selection = select_env(env_id, root, out, algos=algos)
    chosen = {name: r["chosen"] for name, r in selection["runs"].items()}
    tested = {model_of(r): r for r in earlier.values() if r["kind"] == "agent"}
    for run in runs_of(root, env_id, algos):
        name = f"{run.parent.name}/{run.name}"
        for label, selection, source, steps in policies_of(run, chosen.get(name)):
            if label not in earlier:
                found = tested.get((str(run), source, steps))
                if found is None:
                    agent = load_agent(agent_of(run, root, source, steps), env_id)
                    found = outcomes(evaluate(agent, env_id, episodes, TEST_SEED,
                                              policy_name=label))
                earlier[label] = {
                    **found, "kind": "agent", "algo": run.parent.name, "run": str(run),
                    "steps": steps, "source": source, "selection": selection,
                    "finished": finished_steps(run) is not None}
                tested[str(run), source, steps] = earlier[label]
            results[label] = earlier[label]
            print(label, np.mean(results[label]["success"]), flush=True)
    kept = other_agents(earlier, algos, lambda _, r: r["algo"] if r["kind"] == "agent" else "")
    results.update({k: v for k, v in kept.items() if v["kind"] == "agent"})
    reference_label = CONTROLLERS[env_id][0][0]
    ref = results[reference_label]
    from cir_gym.agents.report import iqm

    reference = iqm(np.array(ref["final_feature_error"]))
    lines = [f"# Agents on {env_id.split('/')[1]} against tuned IBVS", "",
             f"Written by `python scripts/research/eval_vs_agents.py evaluate --env {env_id} "
             f"--episodes {episodes}{algo_option(algos)}`: seeds {TEST_SEED}–"
             f"{TEST_SEED + episodes - 1} (held out "
             "from training, its evaluations and the study), deterministic actions, "
             "`cir_gym.evaluation.evaluate`. Success: final feature error < 1 px, no feature "
             "lost, no joint limit. Final error: IQM over the episodes (over seeds × episodes "
             "for an algorithm's seeds together) with rliable's 95 % stratified-bootstrap "
             "interval; success with Wilson's 95 % interval. Ratio: IQM / tuned IBVS's IQM "
             "(the target: ≤ 3). Per run two models: its final model (its last checkpoint "
             "while in training) and its validation choice — the checkpoint or final model of "
             "the highest success, then the lowest final-error IQM, on the validation seeds "
             f"{VALIDATION_SEED}–{VALIDATION_SEED + VALIDATION_EPISODES - 1} "
             f"(`select`, `{stem.name}_selection.md`). The test seeds choose nothing; do not "
             "take the better of the two rows per run (that would choose on the test seeds)."
             + (" Other agents' rows as their last evaluation left them." if algos else ""),
             "", "| policy | success (95 %) | final error IQM, px (95 %) | ratio to "
             f"{reference_label} | median final error (px) | ended early | convergence time "
             "(s), median |", "|---|---:|---:|---:|---:|---:|---:|"]
    by_algo: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for label, r in results.items():
        f = np.array(r["final_feature_error"])[None, :]
        s = np.array(r["success"], dtype=float)[None, :]
        lines.append(row(label, f, s, int(sum(r["terminated"])),
                         float(np.median(r["convergence_time"])), reference))
        if r["kind"] == "agent":
            by_algo.setdefault((r["algo"], r.get("selection", "final")), []).append(r)
    for (algo, selection), rs in by_algo.items():
        if len(rs) > 1:
            f = np.array([r["final_feature_error"] for r in rs])
            s = np.array([r["success"] for r in rs], dtype=float)
            ended = int(sum(sum(r["terminated"]) for r in rs))
            t = float(np.median([r["convergence_time"] for r in rs]))
            what = "validation choices" if selection == "validation" else \
                "final models (last checkpoints in training)"
            lines.append(row(f"**{algo}, {len(rs)} seeds, {what}**", f, s, ended, t,
                             reference))
    out.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    stem.with_suffix(".json").write_text(json.dumps(
        {"env_id": env_id, "seed": TEST_SEED, "episodes": episodes, "results": results},
        indent=1))
    print("\n".join(lines))
    return stem.with_suffix(".md")


def rotation(episodes: int, root: Path, out: Path) -> Path:
    from cir_gym.agents.policy import load_agent

    from cir_gym.evaluation import evaluate

    env_id = EYE_IN_HAND
    policies: list[tuple[str, Any]] = []
    for run in runs_of(root, env_id):
        try:
            agent_dir, steps, finished = snapshot(run, root)
        except FileNotFoundError:
            continue
        label = f"{run.parent.name} {run.name.replace('_', ' ')} @ {steps / 1e6:.2f} M steps"
        policies.append((label + ("" if finished else " (in training)"),
                         load_agent(agent_dir, env_id)))
    laws = (("tuned:ibvs", "ibvs", True, {}), ("ibvs", "ibvs", False, {}),
            ("ibvs (mean L)", "ibvs", False, {"depth": "mean"}), ("pbvs", "pbvs", False, {}))
    makers = [(label, lambda kw, a=agent: a) for label, agent in policies]
    makers += [(label, lambda kw, n=name, t=tuned, g=gains: controller(env_id, n, t, kw, **g))
               for label, name, tuned, gains in laws]
    rows = ["| policy | " + " | ".join(f"{a:.0f}°" for a in ROTATION_ANGLES)
            + " | convergence region |", "|---|" + "---:|" * (len(ROTATION_ANGLES) + 1)]
    for label, make in makers:
        rates = []
        for deg in ROTATION_ANGLES:
            kwargs = {"start_offset": (0.0, 0.0, 0.0, 0.0, 0.0, float(np.deg2rad(deg)))}
            res = evaluate(make(kwargs), env_id, episodes, ROTATION_SEED, policy_name=label,
                           **kwargs)
            rates.append(res.success_rate)
        region = None  # the largest angle up to which every angle is inside
        for a, r in zip(ROTATION_ANGLES, rates, strict=True):
            if r < REGION_SUCCESS:
                break
            region = a
        cell = f"< {ROTATION_ANGLES[0]:.0f}°" if region is None else f"{region:.0f}°"
        rows.append(f"| {label} | " + " | ".join(f"{100 * r:.0f} %" for r in rates)
                    + f" | {cell} |")
        print(rows[-1], flush=True)
    text = ("# Rotation family: agents against IBVS\n\n"
            "Written by `python scripts/research/eval_vs_agents.py rotation --episodes "
            f"{episodes}`: `{env_id}` from start_offset (0, 0, 0, 0, 0, θ) with the default "
            f"0.1 px feature noise, seeds {ROTATION_SEED}–{ROTATION_SEED + episodes - 1}; "
            "success rate per angle; convergence region: the largest θ up to which every "
            f"angle succeeds in ≥ {100 * REGION_SUCCESS:.0f} % of the episodes.\n\n"
            + "\n".join(rows) + "\n")
    out.mkdir(parents=True, exist_ok=True)
    (out / "rotation.md").write_text(text)
    return out / "rotation.md"


def bench(steps: int, out: Path) -> Path:
    """bench_offpolicy.py's measurement with its env swapped for VisualServo-v1's."""
    import bench_offpolicy as bo
    import gymnasium as gym
    import torch
    from cir_gym.agents.observation import ObservationLayout
    from cir_gym.agents.train import EnvFactory
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)

    def env(n: int = 1) -> Any:
        probe = gym.make(EYE_IN_HAND)
        layout = ObservationLayout.from_space(probe.observation_space)
        return DummyVecEnv([EnvFactory(EYE_IN_HAND, {}, layout)] * n)

    bo._env = env  # the benchmark's env factory, on this task
    from sb3_contrib import TQC, CrossQ

    rows = [("PPO, SB3, 16 envs, n_epochs 10", bo._ppo(8 * 2048)),
            ("SAC, SB3", bo._off_policy(SAC, steps, device="cpu")),
            ("TQC, sb3-contrib", bo._off_policy(TQC, steps, device="cpu")),
            ("CrossQ, sb3-contrib", bo._off_policy(CrossQ, steps, device="cpu"))]
    lines = ["# Off-policy training cost on VisualServo-v1", "",
             "Written by `python scripts/research/eval_vs_agents.py bench --steps "
             f"{steps}` (`bench_offpolicy.py`'s measurement on this env): environment steps "
             "per CPU-second of the training process (`time.process_time`) after a 1200-step "
             "warm-up; off-policy: one gradient step of batch 256 per environment step, "
             "256×256 networks (CrossQ: its batch-normalised critic, no target network); one "
             "torch thread. The env step alone costs ~0.8 ms.", "",
             "| algorithm | env steps per CPU-second |", "|---|---:|",
             *[f"| {a} | {r:.0f} |" for a, r in rows], ""]
    out.mkdir(parents=True, exist_ok=True)
    (out / "offpolicy_bench.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return out / "offpolicy_bench.md"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("select", help="each run's checkpoint chosen on the validation seeds")
    v.add_argument("--env", default=EYE_IN_HAND, choices=sorted(CONTROLLERS))
    e = sub.add_parser("evaluate", help="agents and controllers on the held-out seeds")
    e.add_argument("--env", default=EYE_IN_HAND, choices=sorted(CONTROLLERS))
    e.add_argument("--episodes", type=int, default=100)
    r = sub.add_parser("rotation", help="the rotation family")
    r.add_argument("--episodes", type=int, default=30)
    b = sub.add_parser("bench", help="off-policy CPU cost")
    b.add_argument("--steps", type=int, default=1000)
    for p in (v, e):
        p.add_argument("--algo", action="append", default=None,
                       help="only this agent's runs (<runs>/<Env>/<algo>/seed_*; repeatable)")
    for p in (v, e, r, b):
        p.add_argument("--runs", type=Path, default=RUNS)
        p.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    if args.cmd == "select":
        select_env(args.env, args.runs, args.out, algos=args.algo)
    elif args.cmd == "evaluate":
        evaluate_env(args.env, args.episodes, args.runs, args.out, algos=args.algo)
    elif args.cmd == "rotation":
        rotation(args.episodes, args.runs, args.out)
    else:
        bench(args.steps, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
