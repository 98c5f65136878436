"""The ``cir-gym`` command line through ``cir_gym.cli.main``: list, evaluate, leaderboard.

Episodes last 0.1 s and runs have one episode: the command line is under test, not the
controllers.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering for --video (conftest agrees)

import pytest

import cir_gym
import cir_gym.cli
import cir_gym.scoring.policies
from cir_gym import baselines
from cir_gym.cli import main
from cir_gym.scoring.leaderboard import run_leaderboard

ENV = "cir_gym/JointTracking-v2"
SHORT = ["--episodes", "1", "--set", "episode_duration=0.1"]


def evaluate_argv(*extra: str, policy: str = "computed_torque") -> list[str]:
    return ["evaluate", "--env", ENV, "--policy", policy, *SHORT, *extra]


def test_list_prints_every_environment_and_its_controllers(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for env_id in cir_gym.ENVIRONMENTS:
        assert env_id in out
        block = out.split(env_id, 1)[1].split("\ncir_gym/", 1)[0]  # this id's lines only
        for controller in baselines.available(env_id):
            assert controller in block, (env_id, controller)


def test_evaluate_writes_the_plot_and_the_video(tmp_path, capsys):
    plot, video = tmp_path / "x.png", tmp_path / "x.gif"
    assert main(evaluate_argv("--plot", str(plot), "--video", str(video))) == 0
    assert plot.stat().st_size > 0 and video.stat().st_size > 0
    out = capsys.readouterr().out
    assert f"plot: {plot}" in out and f"video: {video}" in out


@pytest.mark.parametrize(
    "option, path, allowed",
    [
        ("--video", "x.avi", ".mp4, .gif"),
        ("--video", "x", ".mp4, .gif"),
        ("--plot", "x.jpg", ".png"),
    ],
)
def test_a_bad_output_extension_exits_2_before_evaluating(
    option, path, allowed, tmp_path, monkeypatch, capsys
):
    def no_evaluation(*args, **kwargs):
        raise AssertionError("the extension must be checked before evaluating")

    monkeypatch.setattr(cir_gym.cli, "evaluate", no_evaluation)
    assert main(evaluate_argv(option, str(tmp_path / path))) == 2
    err = capsys.readouterr().err
    assert option in err and allowed in err and "Traceback" not in err


@pytest.mark.parametrize(
    "setting, needle",
    [
        ("omega_n=abc", "'omega_n'"),
        ("omega_n=[1, 2]", "'omega_n'"),
        ("omega_n=True", "'omega_n'"),
        ("episode_duration=abc", "episode_duration"),
    ],
)
def test_a_setting_of_the_wrong_type_exits_2_with_a_message(setting, needle, capsys):
    assert main(evaluate_argv("--set", setting)) == 2
    err = capsys.readouterr().err
    assert err.startswith("cir-gym: error:") and needle in err


def test_a_rendering_failure_exits_2_with_a_message(tmp_path, monkeypatch, capsys):
    def no_gl(*args, **kwargs):
        raise RuntimeError("MuJoCo could not create an OpenGL context")

    monkeypatch.setattr(cir_gym.cli, "record_video", no_gl)
    assert main(evaluate_argv("--video", str(tmp_path / "x.mp4"))) == 2
    err = capsys.readouterr().err
    assert "x.mp4" in err and "OpenGL context" in err


def test_leaderboard_command_passes_its_options_on(tmp_path, monkeypatch):
    """The command's wiring; the job itself (too long at full episode length) is tested below."""
    calls = []
    monkeypatch.setattr(
        "cir_gym.scoring.leaderboard.run_leaderboard",
        lambda out, **kwargs: calls.append((out, kwargs)),
    )
    argv = ["leaderboard", "--episodes", "1", "--seed", "3", "--out", str(tmp_path)]
    assert main([*argv, "--env", "cir_gym:cir_gym/RedundantIK-v4", "--env", ENV]) == 0
    assert calls == [
        (tmp_path, {"episodes": 1, "seed": 3, "envs": ["cir_gym/RedundantIK-v4", ENV],
                    "videos": True})
    ]
    assert main([*argv, "--env", "cir_gym/Nope-v1"]) == 2
    calls.clear()
    assert main(["leaderboard", "--env", "JointTracking-v2", "--no-videos"]) == 0
    assert calls == [
        (cir_gym.cli.Path("runs/leaderboard"),
         {"episodes": cir_gym.cli.LEADERBOARD_EPISODES, "seed": 1000, "envs": [ENV],
          "videos": False})
    ]


def test_leaderboard_ranks_every_controller_and_draws_every_variant(tmp_path):
    env_id = "cir_gym/ElasticJointTracking-v3"
    md = run_leaderboard(
        tmp_path, episodes=1, envs=[env_id], workers=2, env_overrides={"episode_duration": 0.1}
    ).read_text()
    assert f"## {env_id}" in md
    for controller in baselines.available(env_id):
        assert f"| {controller} |" in md
    variants = cir_gym.ENVIRONMENTS[env_id][0].leaderboard_variants
    assert len(list(tmp_path.glob("*.png"))) == len(variants)


def test_sweep_command_passes_its_options_on(tmp_path, monkeypatch, capsys):
    """The command's wiring (the sweep itself is tested in tests/test_sweep.py)."""
    from cir_gym.scoring.sweep import SweepSummary

    calls = []

    def fake(grid, out, **kwargs):
        calls.append((grid, out, kwargs))
        return SweepSummary(4, 1, 3, 0, 2.0, tmp_path / "results.parquet")

    monkeypatch.setattr("cir_gym.scoring.sweep.run_sweep", fake)
    argv = ["sweep", "g.yaml", "--out", str(tmp_path), "--workers", "2", "--ray", "auto"]
    assert main(argv) == 0
    assert calls == [("g.yaml", str(tmp_path), {"workers": 2, "ray": "auto", "retries": 2})]
    assert "4 tasks: 1 already finished, 3 run (0 failed)" in capsys.readouterr().out
    assert main(["sweep", "g.yaml", "--out", str(tmp_path), "--workers", "0"]) == 2
    assert main(["sweep", "g.yaml", "--out", str(tmp_path), "--retries", "-1"]) == 2


@pytest.mark.parametrize(
    "grid, needle",
    [
        ("evaluate: {envs: [cir_gym/Nope-v1]}", "unknown environment 'cir_gym/Nope-v1'"),
        ("evaluate: [1, 2]", "'evaluate' must be a mapping"),
        ("evaluate: {envs: [cir_gym/JointTracking-v2", "not valid YAML"),
    ],
)
def test_a_bad_grid_exits_2_with_a_message(grid, needle, tmp_path, capsys):
    path = tmp_path / "grid.yaml"
    path.write_text(grid)
    assert main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cir-gym: error:") and needle in err and "Traceback" not in err
    assert main(["sweep", str(tmp_path / "none.yaml"), "--out", str(tmp_path)]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_leaderboard_from_a_directory_without_a_sweep_exits_2(tmp_path, capsys):
    assert main(["leaderboard", "--from", str(tmp_path)]) == 2
    assert "no sweep table" in capsys.readouterr().err


def test_train_command_passes_its_hyperparameter_file_on(tmp_path, monkeypatch):
    """``--hyperparams`` reaches ``agents.train.train`` (the default file when omitted)."""
    pytest.importorskip("stable_baselines3")
    calls = []
    monkeypatch.setattr("cir_gym.agents.train.train", lambda env_id, algo, **kw: calls.append(kw))
    argv = ["train", "--env", "cir_gym/RedundantIK-v4", "--out", str(tmp_path)]
    hp = "agents/hyperparams/levers/rik_base.yml"
    assert main([*argv, "--hyperparams", hp]) == 0
    assert main(argv) == 0
    assert [c["hyperparams_path"] for c in calls] == [hp, None]
    assert calls[0]["out"] == str(tmp_path)


# ---------------------------------------------------------------------- scripts/eval_peg_in_hole
def _merge_many(store: str, worker: int, n: int) -> None:
    from pathlib import Path

    from scripts.research.eval_peg_in_hole import merge_rows

    for i in range(n):
        merge_rows(Path(store), {f"{worker}/{i}": {"worker": worker, "i": i}})


def test_parallel_runs_keep_every_row_of_agents_json(tmp_path):
    """Four processes add 25 rows each to one agents.json: the locked read-merge-write keeps
    all 100 (the unlocked one lost the rows another process wrote between its read and its
    write), leaves no temporary file and keeps the file's mode."""
    import json
    import multiprocessing

    store = tmp_path / "agents.json"
    store.write_text(json.dumps({"old": {"kept": True}}))
    store.chmod(0o644)
    fork = multiprocessing.get_context("fork")  # the workers only read and write JSON
    workers = [fork.Process(target=_merge_many, args=(str(store), w, 25)) for w in range(4)]
    for p in workers:
        p.start()
    for p in workers:
        p.join(120)
    assert [p.exitcode for p in workers] == [0, 0, 0, 0]
    rows = json.loads(store.read_text())
    assert set(rows) == {"old"} | {f"{w}/{i}" for w in range(4) for i in range(25)}
    assert sorted(f.name for f in tmp_path.iterdir()) == ["agents.json"]
    assert store.stat().st_mode & 0o777 == 0o644


def test_a_stored_peg_row_is_reused_only_on_its_own_env_version():
    """eval_peg_in_hole --resume: a row stored before PegInHole-v2 (no env_id: measured on v0,
    whose failed episodes end with another reward) is not taken for a v1 run; a v1 row is;
    tables name the version their rows ran on."""
    import json
    from pathlib import Path

    from scripts.research.eval_peg_in_hole import ENV_ID, _env_names, _key

    committed = Path(__file__).resolve().parents[1] / "results" / "peg_in_hole"
    old = json.loads((committed / "results.json").read_text())["main"][0]
    assert "env_id" not in old
    asked = {k: old[k] for k in ("controller", "episodes", "env_kwargs")}
    asked["gains"] = old.get("gains")
    assert _key(old) != _key({**asked, "env_id": ENV_ID})
    assert _key({**old, "env_id": ENV_ID}) == _key({**asked, "env_id": ENV_ID})
    assert _env_names([old]) == "PegInHole-v0"
    assert _env_names([old, {**old, "env_id": ENV_ID}]) == "PegInHole-v0, PegInHole-v2"


def test_a_stage_replaces_only_its_part_of_results_json(tmp_path):
    """eval_peg_in_hole: a --stage main run keeps the sweeps another run wrote to results.json
    since it started (it replaces only its own part, under the lock), and the markdown built
    from the committed results is the committed peg_in_hole.md."""
    import json
    from pathlib import Path

    from scripts.research.eval_peg_in_hole import SWEEP_PARTS, _write

    committed = Path(__file__).resolve().parents[1] / "results" / "peg_in_hole"
    stored = json.loads((committed / "results.json").read_text())
    assert stored["main"] and all(stored[p] for p in SWEEP_PARTS)
    text = _write(tmp_path, stored, ())  # nothing stored yet: the file is empty of parts
    assert "## Against clearance" not in text
    (tmp_path / "results.json").write_text(json.dumps(stored))  # another run's sweeps
    stale = {"main": stored["main"][:1], "clearance": [], "uncertainty": []}  # loaded earlier
    text = _write(tmp_path, stale, ("main",))
    merged = json.loads((tmp_path / "results.json").read_text())
    assert merged["main"] == stored["main"][:1]
    assert all(merged[p] == stored[p] for p in SWEEP_PARTS)
    assert "## Against clearance" in text
    assert _write(tmp_path, stored, ("main",)) == (committed / "peg_in_hole.md").read_text()


def test_a_tuned_controller_runs_at_the_gains_tuned_for_exactly_these_arguments(tmp_path,
                                                                                monkeypatch):
    """``tuned:<controller>`` is the controller at the gains of results/tuning/<Env>.json's
    study for exactly the env arguments asked (the payload variant's, not the exact model's);
    the leaderboard runs it on the variants it was tuned for only, and names a variant without
    a study instead of guessing."""
    import json

    from cir_gym.scoring.leaderboard import jobs_for
    from cir_gym.scoring.policies import PolicyError, make_policy, policy_names

    rows = [
        {"variant": "exact model", "env_kwargs": {}, "controller": "pd_gravity",
         "tuned": {"omega": 50.0, "zeta": 0.7}},
        {"variant": "unknown 3 kg payload", "env_kwargs": {"payload_mass": 3.0},
         "controller": "pd_gravity", "tuned": {"omega": 120.0, "zeta": 1.5}},
    ]
    (tmp_path / "JointTracking-v2.json").write_text(json.dumps(rows))
    monkeypatch.setattr(cir_gym.scoring.policies, "TUNED_GAINS_DIR", tmp_path)
    assert "tuned:pd_gravity" in policy_names(ENV)
    assert "tuned:computed_torque" not in policy_names(ENV)
    exact = make_policy(ENV, "tuned:pd_gravity", {}, {})
    payload = make_policy(ENV, "tuned:pd_gravity", {"payload_mass": 3.0}, {})
    assert (exact.gains.omega, exact.gains.zeta) == (50.0, 0.7)
    assert (payload.gains.omega, payload.gains.zeta) == (120.0, 1.5)
    assert make_policy(ENV, "tuned:pd_gravity", {}, {"zeta": 2.0}).gains.zeta == 2.0  # --set
    with pytest.raises(PolicyError, match=r"not tuned .* with \{'drive': 'industrial'\}"):
        make_policy(ENV, "tuned:pd_gravity", {"drive": "industrial"}, {})
    tuned_jobs = {v for _, v, _, p in jobs_for(ENV) if p == "tuned:pd_gravity"}
    assert tuned_jobs == {"exact model", "unknown 3 kg payload"}


def test_tuned_gains_hold_whatever_the_reward_arguments():
    """A study's gains are found again with reward-only arguments changed (the reward is not
    the controller's business) and not when a task argument differs."""
    from cir_gym.scoring.policies import PolicyError, tuned_gains

    jt = "cir_gym/JointTracking-v2"
    plain = tuned_gains(jt, "computed_torque", {})
    assert tuned_gains(jt, "computed_torque", {"torque_weight": 0.5}) == plain
    payload = tuned_gains(jt, "computed_torque", {"payload_mass": 3.0})
    assert payload != plain
    assert tuned_gains(jt, "computed_torque", {"payload_mass": 3.0, "charge_unplayed_steps": True,
                                               "error_scales": (0.5,)}) == payload
    with pytest.raises(PolicyError, match="was not tuned"):
        tuned_gains(jt, "computed_torque", {"payload_mass": 1.0, "torque_weight": 0.5})
    cart = "cir_gym/CartesianTracking-v1"
    plain = tuned_gains(cart, "os_khatib", {})
    assert tuned_gains(cart, "os_khatib", {"charge_unplayed_steps": False}) == plain


def test_the_shipped_tuning_files_give_every_tuned_row_its_gains():
    """Every study in results/tuning/<Env>.json is found again by its own env arguments (a
    tuple such as VisualServo's camera_error matches the JSON's list)."""
    import json

    from cir_gym.scoring.policies import TUNED_GAINS_DIR, tuned_gains

    for env_id in cir_gym.ENVIRONMENTS:
        path = TUNED_GAINS_DIR / f"{env_id.split('/')[-1]}.json"
        if not path.is_file():
            continue
        cls = cir_gym.ENVIRONMENTS[env_id][0]
        for r in json.loads(path.read_text()):
            kwargs = cls.leaderboard_variants[r["variant"]]
            assert tuned_gains(env_id, r["controller"], kwargs) == r["tuned"], (env_id, r)


# ---------------------------------------------------------------------- a new user's mistakes
@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--env", "cir_gym/JointTraking-v1", "--policy", "pd_gravity"],
         "did you mean 'cir_gym/JointTracking-v2'"),
        (["--env", "JointTracking", "--policy", "pd_gravity"],
         "did you mean 'cir_gym/JointTracking-v2'"),
        (["--env", ENV, "--policy", "pd_gravty"], "did you mean 'pd_gravity'"),
        (["--env", ENV, "--policy", "computed_torqe"], "did you mean 'computed_torque'"),
        (["--env", ENV, "--policy", "ppo_100hz@JointTracking-v1"],
         "did you mean 'agent:ppo_100hz@JointTracking-v1'"),
        (["--env", ENV, "--policy", "pd_gravity", "--set", "paylod_mass=3"],
         "did you mean 'payload_mass'"),
    ],
)
def test_a_misspelled_id_policy_or_setting_gets_a_did_you_mean(argv, needle, capsys):
    assert main(["evaluate", *argv, "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cir-gym: error:") and needle in err and "Traceback" not in err


def test_the_cir_gym_prefix_is_optional(capsys):
    assert main(["evaluate", "--env", "JointTracking-v2", "--policy", "pd_gravity", *SHORT]) == 0
    assert "pd_gravity" in capsys.readouterr().out


def test_a_bad_environment_value_is_reported_in_our_words_before_any_work(monkeypatch, capsys):
    """``--set payload_mass=abc``: the option, the argument, the value and what is allowed, not
    Gymnasium's "was raised from the environment creator" wrapper; nothing evaluated."""
    monkeypatch.setattr(cir_gym.cli, "evaluate", lambda *a, **k: pytest.fail("evaluated"))
    for setting, allowed in [("payload_mass=abc", "must be a number"),
                             ("payload_mass=-1", "must be in [0.0, 50.0]"),
                             ("drive=fast", "one of ['ideal', 'industrial']")]:
        assert main(evaluate_argv("--set", setting, policy="pd_gravity")) == 2
        err = capsys.readouterr().err
        assert f"--set {setting}:" in err and allowed in err, err
        assert "environment creator" not in err and "Traceback" not in err
    assert main(evaluate_argv("--set", "payload_mass=abc")) == 2
    assert "payload_mass defaults to 0.0" in capsys.readouterr().err


def test_every_evaluate_option_has_help_and_its_default(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", "--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps the lines
    parser = cir_gym.cli.build_parser()
    evaluate = next(
        a for a in parser._subparsers._group_actions[0].choices.items() if a[0] == "evaluate"
    )[1]
    for action in evaluate._actions:
        if action.dest == "help":
            continue
        assert action.help, action.dest
        assert action.required or "default" in action.help, action.dest
    assert "(default: 5)" in text and "(default: 0)" in text


def test_version(capsys):
    import importlib.metadata

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"cir-gym {importlib.metadata.version('cir-gym')}"


def test_ray_auto_without_a_cluster_says_how_to_start_one(tmp_path, monkeypatch, capsys):
    pytest.importorskip("ray")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    grid = tmp_path / "grid.yaml"
    grid.write_text(f"evaluate: {{envs: [{ENV}], policies: [pd_gravity], episodes: 1}}")
    assert main(["sweep", str(grid), "--out", str(tmp_path / "out"), "--ray", "auto"]) == 2
    err = capsys.readouterr().err
    assert "ray start --head" in err and "Traceback" not in err and "--address" not in err


# ---------------------------------------------------------------------- plugin policies
PLUGIN = """
import numpy as np


class HoldStill:
    \"\"\"Zero torque: a third party's policy with SB3's predict.\"\"\"

    def __init__(self, n):
        self.n = n

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.zeros(self.n), state


def make(env_id, env_kwargs):
    import cir_gym  # noqa: F401
    import gymnasium as gym

    env = gym.make(env_id, **env_kwargs)
    n = env.action_space.shape[0]
    env.close()
    return HoldStill(n)


make.env_ids = ["cir_gym/JointTracking-v2"]


def broken(env_id, env_kwargs):
    return object()
"""


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """A distribution on sys.path (a folder with a ``*.dist-info/entry_points.txt``) that adds
    ``plugin:hold_still`` (JointTracking only) and ``plugin:broken`` (no predict)."""
    site = tmp_path / "site"
    (site / "my_policies-0.1.dist-info").mkdir(parents=True)
    (site / "my_policies.py").write_text(PLUGIN)
    (site / "my_policies-0.1.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: my-policies\nVersion: 0.1\n"
    )
    (site / "my_policies-0.1.dist-info" / "entry_points.txt").write_text(
        "[cir_gym.policies]\nhold_still = my_policies:make\nbroken = my_policies:broken\n"
    )
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", str(site))  # the leaderboard's spawned workers
    cir_gym.scoring.policies.plugin_factories(refresh=True)
    yield site
    monkeypatch.undo()
    cir_gym.scoring.policies._LOADED.clear()
    cir_gym.scoring.policies.plugin_factories(refresh=True)


def test_an_installed_plugin_policy_is_listed_evaluated_and_ranked(plugin, tmp_path, capsys):
    from cir_gym.scoring.policies import policy_names

    assert "plugin:hold_still" in policy_names(ENV)
    assert "plugin:hold_still" not in policy_names("cir_gym/PegInHole-v2")  # its env_ids
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "plugin:hold_still (my_policies:make)" in out
    assert "plugin:hold_still" in out.split(ENV, 1)[1].split("\ncir_gym/", 1)[0]

    assert main(evaluate_argv(policy="plugin:hold_still")) == 0
    assert "plugin:hold_still" in capsys.readouterr().out
    assert main(evaluate_argv(policy="plugin:hold_stil")) == 2
    assert "did you mean 'plugin:hold_still'" in capsys.readouterr().err
    assert main(evaluate_argv(policy="plugin:broken")) == 2
    assert "no predict" in capsys.readouterr().err

    from cir_gym.scoring.leaderboard import jobs_for, run_job

    jobs = [j for j in jobs_for(ENV, {"episode_duration": 0.1}) if j[3].startswith("plugin:")]
    assert {j[3] for j in jobs} == {"plugin:hold_still", "plugin:broken"}
    hold = next(j for j in jobs if j[3] == "plugin:hold_still")
    key, result, _ = run_job(hold, 1, 1000)
    assert key[2] == result.policy_name == "plugin:hold_still" and len(result.episodes) == 1


def test_a_failing_run_is_listed_and_the_main_job_goes_on(plugin, tmp_path, monkeypatch, capsys):
    """``plugin:broken`` fails in its worker: the other runs are ranked, the failure is listed
    in leaderboard.md and on stderr, and ``cir-gym leaderboard`` exits 1."""
    from cir_gym.scoring import leaderboard

    only = ("pd_gravity", "plugin:broken")
    real = leaderboard.jobs_for
    monkeypatch.setattr(leaderboard, "jobs_for",
                        lambda e, o=None: [j for j in real(e, o) if j[3] in only])
    monkeypatch.setattr(leaderboard, "_multi_seed_agents", lambda e, kw: [])
    out = tmp_path / "lb"
    argv = ["leaderboard", "--env", ENV, "--episodes", "1", "--out", str(out), "--no-videos"]
    assert main(argv) == 1
    md = (out / "leaderboard.md").read_text()
    assert "| pd_gravity |" in md and "## Failed runs" in md and "broken" in md
    assert "has no predict" in capsys.readouterr().err
