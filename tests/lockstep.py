"""A batched env against one single env per copy, in lockstep (imported by tests/test_vector_*.py).

Copy i of ``reset(seed=s)`` must be the single env after ``reset(seed=s + i)`` and, after each of
its episodes ends, after a plain ``reset()`` (the same generator): :func:`lockstep` steps both
with the same actions and asserts every observation, reward, end, numeric step info, final
observation, final info, success and episode metric equal to the stated tolerance.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: keys of a final info that are not step infos
_EPISODE_KEYS = ("episode_metrics", "is_success")


@dataclass
class Lockstep:
    """What the singles saw: every step's info per copy, and the last infos of ended episodes.

    Attributes:
        infos: (steps, N) the single envs' step infos.
        ends: the single envs' last infos of the episodes that ended, in the order they ended.
        resets: the single envs' reset infos after those ends, in the same order.
    """

    infos: list[list[dict]] = field(default_factory=list)
    ends: list[dict] = field(default_factory=list)
    resets: list[dict] = field(default_factory=list)


def _numeric(value: Any) -> bool:
    return isinstance(value, (bool, int, float, np.number, np.bool_, np.ndarray))


def assert_close(got: Any, want: Any, tol: float, what: str) -> None:
    np.testing.assert_allclose(
        np.asarray(got, dtype=float), np.asarray(want, dtype=float), rtol=tol, atol=tol,
        err_msg=what,
    )


def assert_obs(got: dict, want: dict, tol: float, what: str) -> None:
    assert set(got) == set(want), what
    for key in want:
        assert_close(got[key], want[key], tol, f"{what} {key}")


def assert_info(batched: dict, i: int, single: dict, tol: float, what: str) -> None:
    """Copy i's entries of a batched info dict equal to a single env's info: every numeric
    entry (nested dicts, e.g. a reset's drawn task, entry by entry) that the batch reports."""
    for key, value in single.items():
        if key in _EPISODE_KEYS or key not in batched:
            continue
        if isinstance(value, dict):
            assert_info(batched[key], i, value, tol, f"{what} {key}")
        elif _numeric(value):
            assert_close(batched[key][i], value, tol, f"{what} {key}")


def assert_same_episodes(batched: Any, sequential: Any, tol: float) -> None:
    """Two :class:`cir_gym.evaluation.EvaluationResult` of the same episodes (``evaluate``'s
    batched and sequential paths): seeds, lengths, outcomes equal, returns and metrics to
    ``tol`` (relative, and absolute near 0)."""
    for got, want in zip(batched.episodes, sequential.episodes, strict=True):
        assert (got.seed, got.length, got.success, got.terminated) == (
            want.seed, want.length, want.success, want.terminated)
        assert_close(got.episode_return, want.episode_return, tol, f"seed {want.seed} return")
        assert set(got.metrics) == set(want.metrics)
        for name, value in want.metrics.items():
            assert_close(got.metrics[name], value, tol, f"seed {want.seed} {name}")


def noisy_actions(policy: Any, std: float, seed: int = 0) -> Callable[..., np.ndarray]:
    """Actions for :func:`lockstep`: ``policy`` on each copy's observation plus Gaussian noise
    of ``std`` (clipped by the env), so copies drift, fail and end at different steps."""
    rng = np.random.default_rng(seed)

    def act(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        a, _ = policy.predict(obs)
        return (a + rng.normal(0.0, std, a.shape)).astype(np.float32)

    return act


def episode_ends(vec_cls: type, single_cls: type, kw: dict, act: Callable[..., np.ndarray],
                 steps: int, tol: float, n: int = 3, seed: int = 5) -> list[dict]:
    """:func:`lockstep` of ``n`` copies of ``vec_cls(**kw)`` against ``single_cls(**kw)``
    envs; the single envs' last infos of the episodes that ended."""
    envs = vec_cls(num_envs=n, nthread=1, **kw)
    singles = [single_cls(**kw) for _ in range(n)]
    seen = lockstep(envs, singles, act, seed=seed, steps=steps, tol=tol)
    envs.close()
    return seen.ends


def sampled_observations(envs: Any, policy: Any, seed: int = 40, steps: int = 24,
                         every: int = 4, std: float = 0.3) -> dict[str, np.ndarray]:
    """Observations (rows stacked) of a batched env driven by ``policy`` plus Gaussian noise of
    ``std`` (generator seeded 0), one batch of rows every ``every`` of ``steps`` steps; closes
    ``envs``."""
    rng = np.random.default_rng(0)
    obs, _ = envs.reset(seed=seed)
    rows = []
    for k in range(steps):
        if k % every == 0:
            rows.append({key: v.copy() for key, v in obs.items()})
        a, _ = policy.predict(obs)
        obs = envs.step(a + rng.normal(0.0, std, a.shape).astype(np.float32))[0]
    envs.close()
    return {key: np.concatenate([r[key] for r in rows]) for key in rows[0]}


def only_copy_ends(envs: Any, single: Any, actions: np.ndarray, i: int, tol: float
                   ) -> tuple[dict, dict]:
    """Step ``envs`` and ``single`` (copy ``i``'s twin, reset alike) with ``actions`` (row
    ``i`` for the single env) until a copy terminates: only copy ``i`` must, on the single
    env's step; its final observation (under gymnasium's masks) is the single env's last one
    and its new row the single env's next reset (the same generator), to ``tol``. Returns the
    batch's and the single env's infos of that step."""
    n = envs.num_envs
    term = np.zeros(n, dtype=bool)
    while not term.any():
        obs, _, term, _, infos = envs.step(actions)
        w_obs, _, w_term, _, w_info = single.step(actions[i])
    ended = [k == i for k in range(n)]
    assert w_term and list(term) == ended and list(infos["_final_obs"]) == ended
    assert_obs(infos["final_obs"][i], w_obs, tol, "final")
    assert_obs(row(obs, i), single.reset()[0], tol, "next reset")
    return infos, w_info


def row(obs: dict, i: int) -> dict:
    """Copy i's observation of a batched Dict observation."""
    return {key: value[i] for key, value in obs.items()}


def lockstep(
    envs: Any,
    singles: list,
    actions: Callable[[int, dict, np.ndarray], np.ndarray],
    *,
    seed: int,
    steps: int,
    tol: float,
) -> Lockstep:
    """Step ``envs`` and ``singles`` (one per copy) with the same actions for ``steps`` steps.

    Args:
        envs: the batched env (SAME_STEP autoreset).
        singles: one single env per copy.
        actions: ``actions(k, obs, episode_start)`` → (N, m), from the batch's observation at
            step k and which copies start an episode there.
        seed: the batch's reset seed (copy i: ``seed + i``).
        steps: batched steps.
        tol: relative and absolute tolerance of every comparison.

    Returns:
        :class:`Lockstep`: what the single envs saw, for the caller's own counts.
    """
    seen = Lockstep()
    obs, reset_infos = envs.reset(seed=seed)
    for i, single in enumerate(singles):
        w_obs, w_reset = single.reset(seed=seed + i)
        assert_obs(row(obs, i), w_obs, tol, "reset")
        assert_info(reset_infos, i, w_reset, tol, "reset")
    start = np.ones(len(singles), dtype=bool)
    for k in range(steps):
        a = actions(k, obs, start)
        obs, rew, term, trunc, infos = envs.step(a)
        start = term | trunc
        seen.infos.append([])
        for i, single in enumerate(singles):
            w_obs, w_rew, w_term, w_trunc, w_info = single.step(a[i])
            seen.infos[-1].append(w_info)
            what = f"step {k} copy {i}"
            assert (bool(term[i]), bool(trunc[i])) == (w_term, w_trunc), what
            assert_close(rew[i], w_rew, tol, f"{what} reward")
            if w_term or w_trunc:
                seen.ends.append(w_info)
                assert infos["_final_obs"][i] and infos["_final_info"][i], what
                assert_obs(infos["final_obs"][i], w_obs, tol, f"{what} final")
                final = infos["final_info"]
                assert_info(final, i, w_info, tol, f"{what} final")
                assert bool(final["is_success"][i]) == w_info["is_success"], what
                for name, value in w_info["episode_metrics"].items():
                    got = final["episode_metrics"][name][i]
                    assert_close(got, value, tol, f"{what} {name}")
                w_obs, w_reset = single.reset()
                seen.resets.append(w_reset)
                assert_info(infos, i, w_reset, tol, f"{what} autoreset")
            else:
                assert not infos.get("_final_obs", np.zeros(len(singles), bool))[i], what
                assert_info(infos, i, w_info, tol, what)
            assert_obs(row(obs, i), w_obs, tol, what)
    return seen



#: tolerances of an SB3 VecEnv stack against its single-env stack: the float32 values the agent
#: sees (observations, rewards, actions), relative; the float64 episode metrics, relative
SB3_RTOL = 1e-6
SB3_METRIC_RTOL = 1e-9


def sb3_step(venv: Any, singles: list[Any], actions: np.ndarray, k: int,
             info_keys: tuple[str, ...] = ("controller_action",)) -> list[tuple[int, bool]]:
    """One ``venv.step(actions)`` of an SB3 VecEnv (SAME_STEP autoreset, ``terminal_observation``)
    against ``singles[i].step(actions[i])`` (a single-env stack with Monitor's ``episode``
    info; reset here after its episode ends): ends, rewards, the step infos ``info_keys``, final
    observations, episode statistics, success, episode metrics and the next observations, to
    :data:`SB3_RTOL` / :data:`SB3_METRIC_RTOL`.

    Returns:
        (copy, terminated) of every copy whose episode ended in this step.
    """
    import pytest

    obs, rew, dones, infos = venv.step(actions)
    ended = []
    for i, env in enumerate(singles):
        what = f"step {k} copy {i}"
        o, r, term, trunc, info = env.step(actions[i])
        assert bool(dones[i]) == (term or trunc), what
        assert rew[i] == pytest.approx(r, rel=SB3_RTOL, abs=SB3_RTOL), what
        for key in info_keys:
            np.testing.assert_allclose(infos[i][key], info[key], rtol=SB3_RTOL, atol=SB3_RTOL,
                                       err_msg=f"{what} {key}")
        if dones[i]:
            ended.append((i, bool(term)))
            np.testing.assert_allclose(infos[i]["terminal_observation"], o, rtol=SB3_RTOL,
                                       atol=SB3_RTOL, err_msg=what)
            assert infos[i]["episode"]["l"] == info["episode"]["l"], what
            assert infos[i]["episode"]["r"] == pytest.approx(info["episode"]["r"],
                                                             rel=SB3_RTOL), what
            assert infos[i]["is_success"] == info["is_success"], what
            for name, value in info["episode_metrics"].items():
                assert infos[i]["episode_metrics"][name] == pytest.approx(
                    value, rel=SB3_METRIC_RTOL, abs=1e-12), f"{what} {name}"
            o, _ = env.reset()
        np.testing.assert_allclose(obs[i], o, rtol=SB3_RTOL, atol=SB3_RTOL, err_msg=what)
    return ended
