"""One ``## `` section of a markdown results file, rewritten by the benchmark that owns it.

Every benchmark script writes its own section of ``results/benchmarks.md`` and keeps the
others, so the scripts can be re-run one at a time in any order. Imported by the scripts of
this directory as a sibling module (``python benchmarks/bench_*.py`` puts it on the path).
"""

from __future__ import annotations

import re
from pathlib import Path


def write_section(path: Path, section: str, body: str) -> None:
    """Replace (or append) ``section`` (its heading line, e.g. ``"## Sweeps"``) in ``path``.

    The section runs from its heading to the next ``## `` heading; every other section and
    the text before the first one are kept byte for byte. A missing file is created with a
    ``# Benchmarks`` title.
    """
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    pattern = re.compile(rf"^{re.escape(section)}\n.*?(?=^## |\Z)", re.S | re.M)
    block = f"{section}\n\n{body.strip()}\n\n"
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text)
    else:
        text = text.rstrip() + "\n\n" + block
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text.rstrip() + "\n")
