"""scripts/research/eval_residual_base.py: which agent it takes, and what it separates on a
shipped residual agent (JointTracking's computed-torque residual, trained under the 3-kg
payload, listed on JointTracking-v2)."""

from __future__ import annotations

import pytest

pytest.importorskip("torch")

from scripts.research.eval_residual_base import main as residual_base
from scripts.research.eval_residual_base import residual_agents

ENV = "cir_gym/JointTracking-v2"
RESIDUAL = "residual_ppo_computed_torque@JointTracking-v1"


def test_env_and_agent_are_required_and_a_wrong_agent_names_the_residual_agents(capsys):
    assert RESIDUAL in residual_agents(ENV)
    assert "ppo_100hz@JointTracking-v1" not in residual_agents(ENV)  # trained from scratch
    with pytest.raises(SystemExit):
        residual_base([])
    assert "--env, --agent" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        residual_base(["--env", ENV, "--agent", "ppo_100hz@JointTracking-v1"])
    err = capsys.readouterr().err
    assert "--agent 'ppo_100hz@JointTracking-v1' is not a shipped residual agent" in err
    assert RESIDUAL in err
    with pytest.raises(SystemExit):
        residual_base(["--env", "cir_gym/AdmittanceContact-v2", "--agent",
                       "residual_ppo_admittance"])
    assert "its residual agents: none" in capsys.readouterr().err


def test_the_base_alone_is_the_variants_controller_where_the_context_is_the_same(tmp_path):
    """JointTracking's computed torque is built from the nominal model whatever the variant, so
    the agent's base alone (its policy's output zeroed) is the leaderboard's computed_torque on
    every variant, episode for episode; the residual itself changes the result."""
    out = tmp_path / "r.md"
    assert residual_base(["--env", ENV, "--agent", RESIDUAL, "--episodes", "1",
                          "--out", str(out)]) == 0
    rows = {r.split("|")[1].strip(): [float(c) for c in r.split("|")[2:5]]
            for r in out.read_text().splitlines()
            if r.startswith("| ") and not r.startswith("| variant")}
    assert {"exact model", "unknown 3 kg payload"} <= set(rows)
    for agent, base, variant in rows.values():
        assert base == variant  # the same 4 significant digits the table prints
        assert agent != pytest.approx(base, rel=1e-3)
