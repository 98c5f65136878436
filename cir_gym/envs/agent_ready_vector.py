"""Native batched agent-ready variants: ``num_envs`` copies of
``cir_gym/AdmittanceContactImpedance-v1`` or ``cir_gym/PegInHoleImpedance-v0`` in one vector
env, their physics the task's batched env on one ``mujoco.batch.Batch``.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/AdmittanceContactImpedance-v1", num_envs=32)  # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)      # copy i is the single variant reset(seed=i)
>>> obs, rew, term, trunc, infos = envs.step(envs.action_space.sample())

What is batched and how (the single variant's ``step``,
:class:`~cir_gym.envs.agent_ready.ImpedanceTaskEnv`, is the specification; each copy equals it
to the tolerance tests/test_vector_agent_ready.py states):

* **The task.** The copies' task is the task's own batched env (``task_vector_class``:
  :class:`~cir_gym.envs.admittance_vector.AdmittanceContactVectorEnv`,
  :class:`~cir_gym.envs.peg_in_hole_vector.PegInHoleVectorEnv`) built with the single
  variant's ``task_arguments`` (torque interface, 500 Hz): a policy step plays its
  ``substeps`` task control steps by calling that env's own task step with (N, 7) normalised
  torques, each copy's task step counter advanced as its ``step`` advances it. Its resets
  (seeding s + i), physics, divergence, metrics and success are used unchanged; its Batch is
  this env's ``batch``.
* **The impedance loop.** One :class:`~cir_gym.impedance.CartesianImpedance` of N arms on the
  nominal model: at every task control step the law τ = Jᵀ(K_p x̃ − K_d ẋ) + g + Nᵀ τ₀ on
  (N, ...) arrays (one Batch of the nominal arm for J, B, g and the poses of all copies).
* **The policy step.** The setpoint move and clamp, the stiffness action, the observation and
  the reward terms are the single variant's own methods (``_move_setpoint``,
  ``_observation``, ``_task_term``, ``_reward_terms``) on (N, ...) arrays; the single
  variant is their one-row case. A copy's start (setpoint at the start pose, K_d from
  diag Λ(q₀), the posture's rest) is the template single variant's ``_start``.
* **Episode ends inside a policy step.** The single variant stops playing task steps when its
  task ends. Here every copy's physics advances with the others (one Batch); a copy whose
  task ended keeps its observation, step infos and final task info (its task's
  ``_episode_end``, taken at its last task step) and its task-term sum stops; the rest of the
  period's task steps of that copy are not used (its generator is put back to its state at
  its end, so their sensor noise draws nothing from the copy's stream), and it is reset in
  the same ``step`` (``SAME_STEP``), as :class:`~cir_gym.envs.vector_base.BatchedTaskEnv`
  resets every copy.

Supported: every argument of the single variant except ``render_mode``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from cir_gym.envs.admittance_vector import AdmittanceContactVectorEnv
from cir_gym.envs.agent_ready import (
    AdmittanceContactImpedanceEnv,
    ImpedanceTaskEnv,
    PegInHoleImpedanceEnv,
)
from cir_gym.envs.peg_in_hole_vector import PegInHoleVectorEnv
from cir_gym.envs.vector_base import BatchedTaskEnv, TaskStep
from cir_gym.impedance import CartesianImpedance

__all__ = [
    "AdmittanceContactImpedanceVectorEnv",
    "ImpedanceVectorEnv",
    "PegInHoleImpedanceVectorEnv",
]

#: the physics-holding attributes of BatchedTaskEnv, taken from the task's batched env
_PHYSICS = ("batch", "_qpos", "_qvel", "_ctrl", "_act")


class ImpedanceVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of an agent-ready variant (``env_class``) driving the task's batched
    env (``task_vector_class``) by its impedance loop (see the module docstring).

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: the single variant's arguments, except ``render_mode``.

    Raises:
        InvalidArgument: ``num_envs`` < 1, ``nthread`` < 0, ``render_mode``, or an argument the
            single variant rejects.
    """

    env_class: ClassVar[type[ImpedanceTaskEnv]]
    #: the task's batched env, driven by (N, 7) torques per task control step
    task_vector_class: ClassVar[type[BatchedTaskEnv]]
    template: ImpedanceTaskEnv
    #: the template's per-episode impedance state: setpoint (p_d (3,), R_d (3, 3)), K_p, K_d
    #: (6,), the damping's design inertia diag Λ(q₀) (6,), the previous action
    episode_state: ClassVar[tuple[str, ...]] = ("p_d", "R_d", "K_p", "K_d", "_m_eff", "_a_prev")

    def _allocate(self) -> None:
        t, N = self.template, self.num_envs
        self.tasks = self.task_vector_class(
            num_envs=N, nthread=self.batch.nthread, **t.task_arguments
        )
        for name in _PHYSICS:  # one simulation: the task env's (the base's Batch is dropped)
            setattr(self, name, getattr(self.tasks, name))
        self.tasks._rngs = self._rngs  # one generator per copy: reset(seed=s) seeds the tasks
        self.impedance = CartesianImpedance(
            t.nominal, "tcp", t.impedance.gains, np.zeros((N, t.nominal.n))
        )
        task_space = t.task.observation_space.spaces
        self._task_obs = {key: np.zeros((N, *box.shape)) for key, box in task_space.items()}
        self._ends: dict[int, dict[str, Any]] = {}  # copy → its task's final info, this step

    # ------------------------------------------------------------------ resets
    def _reset_copy(self, i: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset copy ``i``'s task (the task env's reset: generator, template, Batch row) and
        start its impedance loop as the single variant starts it."""
        t = self.template
        task_obs, info = self.tasks._reset_copy(i)
        self._k[i] = 0
        t._start(task_obs)
        for name in self.episode_state:
            getattr(self, name)[i] = getattr(t, name)
        self.impedance.q_rest[i] = t.impedance.q_rest
        for key, value in task_obs.items():
            self._task_obs[key][i] = value
        return t._obs(), info

    # ------------------------------------------------------------------ step
    def _task_step(self, a: np.ndarray, peak: np.ndarray, k: np.ndarray) -> TaskStep:
        t, tasks, imp, N = self.template, self.tasks, self.impedance, self.num_envs
        obs = self._task_obs
        self.p_d, self.R_d, self.K_p, self.K_d = t._move_setpoint(
            a, *imp.pose(obs["q"]), self.p_d, self.R_d, self.K_p, self.K_d, self._m_eff
        )
        task_sum, played = np.zeros(N), np.zeros(N, dtype=np.int64)
        live, terminated = np.ones(N, dtype=bool), np.zeros(N, dtype=bool)
        held: tuple[dict[str, np.ndarray], dict[str, Any]] | None = None
        self._ends.clear()
        rng_states: dict[int, dict[str, Any]] = {}  # an ended copy's generator at its end
        for _ in range(t.substeps):
            tau = imp.torque(obs["q"], obs["qd"], self.p_d, self.R_d, self.K_p, self.K_d)
            u = np.clip(tau / t.torque_limit, -1.0, 1.0)
            task_k = tasks._k.copy()
            tasks._k += 1  # as the task env's step counts its copies' steps
            obs, _, term, infos = tasks._task_step(u, np.max(np.abs(u), axis=1), task_k)
            task_sum += np.where(live, t._task_term(infos), 0.0)
            played += live
            trunc = tasks._truncated(term)
            ended = live & (term | trunc)
            if not ended.any():
                continue
            for i in np.flatnonzero(ended):  # the task's final info, at its last step
                self._ends[int(i)] = tasks._episode_end(int(i), infos, term[i], trunc[i])
                rng_states[int(i)] = self._rngs[i].bit_generator.state
            terminated |= ended & term
            live &= ~ended
            held = _hold(held, obs, infos, ended)
            if not live.any():
                break
        if held is not None:  # each ended copy as of its last task step
            obs, infos = _restore(held, obs, infos, ~live)
        for i, state in rng_states.items():  # what its unused steps drew (sensor noise) undone
            self._rngs[i].bit_generator.state = state
        self._task_obs = {key: value.copy() for key, value in obs.items()}
        success = np.zeros(N, dtype=bool)
        for i, end in self._ends.items():
            success[i] = end["is_success"]
        terms = t._reward_terms(
            task_sum / played, a, self._a_prev, success, terminated & ~success, self._k
        )
        self._a_prev[:] = a
        reward = sum(terms.values())  # the single variant's order of the terms
        values = {key: v for key, v in infos.items() if not key.startswith(("_", "reward_"))}
        values.update({f"reward_{name}": v for name, v in terms.items()})
        values["task_steps"] = played
        out_obs = t._observation(obs, *imp.pose(obs["q"]), self.p_d, self.R_d, self.K_p)
        return out_obs, reward, terminated, self._step_infos(values)

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        end = self._ends[i]
        return {
            **self._row_info(infos, i),
            "episode_metrics": end["episode_metrics"],
            "is_success": end["is_success"],
        }

    def close_extras(self, **kwargs: Any) -> None:
        self.tasks.close()
        super().close_extras(**kwargs)


def _hold(
    held: tuple[dict[str, np.ndarray], dict[str, Any]] | None,
    obs: dict[str, np.ndarray],
    infos: dict[str, Any],
    rows: np.ndarray,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Keep the ``rows`` (N,) bool of a task step's observation and infos: a copy of both at
    the first call, then those rows written into it."""
    if held is None:
        return {k: v.copy() for k, v in obs.items()}, {k: np.copy(v) for k, v in infos.items()}
    for store, new in zip(held, (obs, infos), strict=True):
        for key, value in new.items():
            store[key][rows] = value[rows]
    return held


def _restore(
    held: tuple[dict[str, np.ndarray], dict[str, Any]],
    obs: dict[str, np.ndarray],
    infos: dict[str, Any],
    rows: np.ndarray,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``obs`` and ``infos`` with the ``rows`` (N,) bool taken from ``held``."""
    for store, new in zip(held, (obs, infos), strict=True):
        for key, value in new.items():
            value[rows] = store[key][rows]
    return obs, infos


class AdmittanceContactImpedanceVectorEnv(ImpedanceVectorEnv):
    """``num_envs`` copies of ``cir_gym/AdmittanceContactImpedance-v1`` on
    :class:`~cir_gym.envs.admittance_vector.AdmittanceContactVectorEnv` (module docstring)."""

    env_class: ClassVar[type[ImpedanceTaskEnv]] = AdmittanceContactImpedanceEnv
    env_id: ClassVar[str] = "cir_gym/AdmittanceContactImpedance-v1"
    task_vector_class: ClassVar[type[BatchedTaskEnv]] = AdmittanceContactVectorEnv



class PegInHoleImpedanceVectorEnv(ImpedanceVectorEnv):
    """``num_envs`` copies of ``cir_gym/PegInHoleImpedance-v0`` on
    :class:`~cir_gym.envs.peg_in_hole_vector.PegInHoleVectorEnv` (module docstring)."""

    env_class: ClassVar[type[ImpedanceTaskEnv]] = PegInHoleImpedanceEnv
    env_id: ClassVar[str] = "cir_gym/PegInHoleImpedance-v0"
    task_vector_class: ClassVar[type[BatchedTaskEnv]] = PegInHoleVectorEnv
