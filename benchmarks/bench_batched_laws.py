"""Batched against sequential evaluation of the operational-space and interaction laws.

    python benchmarks/bench_batched_laws.py [--episodes 10] [--controllers os_khatib ...]
                                            [--envs cir_gym/CartesianTracking-v1 ...]

For every controller of CartesianTracking-v1 (the operational-space laws) and
AdmittanceContact-v2 (the interaction laws, torque interface, the 1e4 N/m variant)
:func:`cir_gym.evaluation.evaluate` runs ``--episodes`` episodes twice in the same run, one
after the other (``batched=False``) and batched on the native vector env (``batched=True``),
and prints wall and process-CPU seconds of each and their ratios, with the largest difference
of the primary metric between the two: 0 for the course controllers, whose batched rows are
their rows alone bit for bit (``--check`` exits with status 1 otherwise).
"""

from __future__ import annotations

import argparse
import time

from cir_gym import baselines
from cir_gym.evaluation import evaluate

ENVS: dict[str, dict] = {
    "cir_gym/CartesianTracking-v1": {},
    "cir_gym/AdmittanceContact-v2": {"stiffness": 1.0e4, "force_ref": 20.0},
}


def register_batched(env_id: str) -> None:
    """Make ``evaluate`` batch ``env_id`` in this process when its batched env exists but is
    not yet listed in ``cir_gym.envs.BATCHED_ENVIRONMENTS`` (AdmittanceContact's)."""
    import cir_gym.envs as envs

    known = {"cir_gym/AdmittanceContact-v2":
             "cir_gym.envs.admittance_vector:AdmittanceContactVectorEnv"}
    if env_id not in envs.BATCHED_ENVIRONMENTS and env_id in known:
        envs.BATCHED_ENVIRONMENTS[env_id] = known[env_id]


def timed(fn, *args, **kwargs):
    """(result, wall s, CPU s) of ``fn(*args, **kwargs)``."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - w0, time.process_time() - c0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--controllers", nargs="+", default=None)
    parser.add_argument("--check", action="store_true",
                        help="exit 1 if a batched metric differs from the sequential one")
    args = parser.parse_args(argv)
    differs = []
    print(f"{'env':30s} {'controller':26s} {'seq wall':>9s} {'bat wall':>9s} {'ratio':>6s} "
          f"{'seq CPU':>8s} {'bat CPU':>8s} {'ratio':>6s} {'max |Δ metric|':>15s}")
    for env_id in args.envs:
        kwargs = ENVS.get(env_id, {})
        register_batched(env_id)
        names = [n for n in baselines.available(env_id)
                 if args.controllers is None or n in args.controllers]
        for name in names:
            policy = baselines.make(name, env_id, env_kwargs=kwargs)
            seq, sw, sc = timed(evaluate, policy, env_id, args.episodes, 0, batched=False,
                                **kwargs)
            bat, bw, bc = timed(evaluate, policy, env_id, args.episodes, 0, batched=True,
                                **kwargs)
            key = seq.primary_metric
            diff = max(
                abs(a.metrics[key] - b.metrics[key])
                for a, b in zip(seq.episodes, bat.episodes, strict=True)
            )
            print(f"{env_id.split('/')[-1]:30s} {name:26s} {sw:9.2f} {bw:9.2f} {sw / bw:6.2f} "
                  f"{sc:8.2f} {bc:8.2f} {sc / bc:6.2f} {diff:15.3g}", flush=True)
            if diff != 0.0:
                differs.append(f"{env_id} {name}")
            del seq, bat
    if args.check and differs:
        raise SystemExit(f"batched != sequential: {', '.join(differs)}")


if __name__ == "__main__":
    main()
