"""Policy factories that fail on purpose, for the sweep's fault tests (tests/test_sweep.py).

A sweep grid names them as ``"tests/sweep_faults.py:flaky"`` (loaded by file path in every
worker, local or Ray); their "gains" say how to fail. Each call appends a line to ``log`` so a
test counts the attempts; on success they return the ``pd_gravity`` controller.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

from cir_gym import baselines


def flaky(env_id: str, env_kwargs: dict[str, Any], gains: dict[str, Any]) -> Any:
    """``mode="raise"``: raise RuntimeError while the file ``flag`` exists;
    ``mode="kill_once"``: on the first call (no file ``flag`` yet) create it and SIGKILL this
    worker process; ``mode="ok"``: never fail."""
    flag = Path(gains["flag"])
    with Path(gains["log"]).open("a") as f:
        f.write(f"{gains['mode']} {os.getpid()}\n")
    if gains["mode"] == "raise" and flag.exists():
        raise RuntimeError(f"injected failure while {flag.name} exists")
    if gains["mode"] == "kill_once" and not flag.exists():
        flag.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return baselines.make("pd_gravity", env_id, env_kwargs=env_kwargs)
