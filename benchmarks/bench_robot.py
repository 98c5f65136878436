"""Cost of cir_gym.robot.Robot's dynamics calls against the raw MuJoCo C calls, on iiwa14.

    python benchmarks/bench_robot.py [--calls 500] [--repeat 80] [--seed 0] [--target 3]

Every call gets a fresh random configuration (so no caching helps either side). What the
"raw MuJoCo" column measures, per call, on its own MjModel/MjData with preallocated outputs
(the Robot side does the same C calls plus argument validation and a copy of the result):

- inertia(q):    d.qpos[:] = q; mj_kinematics, mj_comPos, mj_crb, mj_fullM
- bias(q, qd):   d.qpos[:] = q; d.qvel[:] = qd; mj_kinematics, mj_comPos, mj_comVel, mj_rne
- jacobian(...): d.qpos[:] = q; mj_kinematics, mj_comPos, mj_jacSite

Target: Robot ≤ 3× raw (``--target``). Each pair of loops is timed alternately and the best of
``--repeat`` is kept, so a loaded machine slows both sides alike. Also times the numpy
chapter-2 functions ``cir_gym.dynamics.rnea`` and ``inertia_matrix`` per call (single
configuration and batched), after checking them against MuJoCo. Prints markdown tables; exit
status 1 if a ratio exceeds the target (an import error is a traceback, never a skip).
"""

from __future__ import annotations

import argparse
import sys
import timeit
from collections.abc import Callable

import mujoco
import numpy as np

from cir_gym.dynamics import inertia_matrix, rnea
from cir_gym.robot import Robot, load_model

SITE = "flange"
TARGET = 3.0

# The C calls of the raw side of each row (kept in sync with the raw_* loops below).
RAW_INERTIA = "mj_kinematics + mj_comPos + mj_crb + mj_fullM"
RAW_BIAS = "mj_kinematics + mj_comPos + mj_comVel + mj_rne"
RAW_JACOBIAN = "mj_kinematics + mj_comPos + mj_jacSite"


def best_per_call(loop: Callable[[], None], calls: int, repeat: int) -> float:
    """Best-of-``repeat`` seconds per call of ``loop`` (which makes ``calls`` calls)."""
    loop()  # warm-up
    return min(timeit.repeat(loop, number=1, repeat=repeat)) / calls


def best_pair(
    mine: Callable[[], None], raw: Callable[[], None], calls: int, repeat: int
) -> tuple[float, float]:
    """Best-of-``repeat`` s/call of two loops timed alternately (so both see the same load)."""
    mine()
    raw()
    t_mine, t_raw = [], []
    for _ in range(repeat):
        t_mine.append(timeit.timeit(mine, number=1))
        t_raw.append(timeit.timeit(raw, number=1))
    return min(t_mine) / calls, min(t_raw) / calls


def robot_benchmarks(calls: int, repeat: int, seed: int) -> list[tuple[str, str, float, float]]:
    """(name, raw C calls, Robot s/call, raw s/call) for inertia, bias, jacobian (name, id)."""
    robot = Robot.from_name("iiwa14")
    m = load_model("iiwa14")  # the raw side's own model and data
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    Q = rng.uniform(robot.lower, robot.upper, (calls, robot.n))
    QD = rng.uniform(-1.0, 1.0, (calls, robot.n))
    M = np.zeros((m.nv, m.nv))
    tau = np.zeros(m.nv)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    sid = robot.site_id(SITE)

    def raw_inertia() -> None:
        for q in Q:
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_crb(m, d)
            mujoco.mj_fullM(m, d, M)

    def raw_bias() -> None:
        for q, qd in zip(Q, QD, strict=True):
            d.qpos[:] = q
            d.qvel[:] = qd
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            mujoco.mj_rne(m, d, 0, tau)

    def raw_jacobian() -> None:
        for q in Q:
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jacp, jacr, sid)

    def robot_inertia() -> None:
        for q in Q:
            robot.inertia(q)

    def robot_bias() -> None:
        for q, qd in zip(Q, QD, strict=True):
            robot.bias(q, qd)

    def robot_jacobian_name() -> None:
        for q in Q:
            robot.jacobian(SITE, q)

    def robot_jacobian_id() -> None:
        for q in Q:
            robot.jacobian(sid, q)

    # same results (a benchmark of wrong numbers is worthless)
    ref = _raw_one(m, d, Q[0], QD[0], sid)
    for got, want in zip(
        (robot.inertia(Q[0]), robot.bias(Q[0], QD[0]), robot.jacobian(SITE, Q[0])), ref, strict=True
    ):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)

    rows = []
    for name, raw_calls, mine, raw in (
        ("inertia(q)", RAW_INERTIA, robot_inertia, raw_inertia),
        ("bias(q, qd)", RAW_BIAS, robot_bias, raw_bias),
        (f"jacobian('{SITE}', q)", RAW_JACOBIAN, robot_jacobian_name, raw_jacobian),
        ("jacobian(site_id, q)", RAW_JACOBIAN, robot_jacobian_id, raw_jacobian),
    ):
        rows.append((name, raw_calls, *best_pair(mine, raw, calls, repeat)))
    return rows


def _raw_one(
    m: mujoco.MjModel, d: mujoco.MjData, q: np.ndarray, qd: np.ndarray, sid: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    M, tau = np.zeros((m.nv, m.nv)), np.zeros(m.nv)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    d.qpos[:], d.qvel[:] = q, qd
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_crb(m, d)
    mujoco.mj_fullM(m, d, M)
    mujoco.mj_comVel(m, d)
    mujoco.mj_rne(m, d, 0, tau)
    mujoco.mj_jacSite(m, d, jacp, jacr, sid)
    return M, tau, np.vstack((jacp, jacr))


def numpy_benchmarks(calls: int, repeat: int, seed: int) -> list[tuple[str, float]]:
    """(name, s/call) of cir_gym.dynamics.rnea / inertia_matrix, single and batched."""
    robot = Robot.from_name("iiwa14")
    model = robot.model
    rng = np.random.default_rng(seed)
    n = robot.n
    calls = max(1, calls // 10)  # numpy is slower; fewer calls keep the run short
    Q = rng.uniform(robot.lower, robot.upper, (calls, n))
    QD = rng.uniform(-1.0, 1.0, (calls, n))
    QDD = rng.uniform(-1.0, 1.0, (calls, n))
    # correctness against MuJoCo before timing
    tau_ref = robot.inertia(Q[0]) @ QDD[0] + robot.bias(Q[0], QD[0])
    np.testing.assert_allclose(rnea(model, Q[0], QD[0], QDD[0]), tau_ref, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(
        inertia_matrix(model, Q[0]), robot.inertia(Q[0]), rtol=1e-8, atol=1e-10
    )

    def one_rnea() -> None:
        for q, qd, qdd in zip(Q, QD, QDD, strict=True):
            rnea(model, q, qd, qdd)

    def one_inertia() -> None:
        for q in Q:
            inertia_matrix(model, q)

    batch = 1000
    QB = rng.uniform(robot.lower, robot.upper, (batch, n))
    QDB, QDDB = rng.uniform(-1, 1, (batch, n)), rng.uniform(-1, 1, (batch, n))
    return [
        ("dynamics.rnea(model, q, qd, qdd)", best_per_call(one_rnea, calls, repeat)),
        ("dynamics.inertia_matrix(model, q)", best_per_call(one_inertia, calls, repeat)),
        (
            f"dynamics.rnea, batch of {batch} (per q)",
            best_per_call(lambda: rnea(model, QB, QDB, QDDB), batch, repeat),
        ),
        (
            f"dynamics.inertia_matrix, batch of {batch} (per q)",
            best_per_call(lambda: inertia_matrix(model, QB), batch, repeat),
        ),
    ]


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks and print the tables; 0 if every ratio is within the target, else 1."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=500, help="calls per timing loop")
    parser.add_argument("--repeat", type=int, default=80, help="timing loops (best is kept)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--target", type=float, default=TARGET, help="largest Robot/raw ratio for exit status 0"
    )
    args = parser.parse_args(argv)
    if args.calls < 1 or args.repeat < 1:
        parser.error("--calls and --repeat must be at least 1")

    rows = robot_benchmarks(args.calls, args.repeat, args.seed)
    print(f"iiwa14, {args.calls} fresh random configurations per loop, best of {args.repeat}")
    print(
        "raw MuJoCo = set d.qpos (and d.qvel) from the same q (q̇), then the C calls listed, "
        "preallocated outputs; Robot = the same C calls + validation of q (q̇) + a copy\n"
    )
    print("| call | raw MuJoCo calls | Robot (µs) | raw MuJoCo (µs) | ratio | target |")
    print("|---|---|---:|---:|---:|---|")
    ok = True
    for name, raw_calls, mine, raw in rows:
        ratio = mine / raw
        ok &= ratio <= args.target
        verdict = "ok" if ratio <= args.target else "MISSED"
        print(
            f"| {name} | {raw_calls} | {mine * 1e6:.2f} | {raw * 1e6:.2f} | {ratio:.2f}× "
            f"| ≤ {args.target:g}× {verdict} |"
        )
    print()
    print("| numpy (chapter 2) | µs per call |")
    print("|---|---:|")
    for name, t in numpy_benchmarks(args.calls, args.repeat, args.seed):
        print(f"| {name} | {t * 1e6:.1f} |")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
