"""Build the documentation site: stage the sources, generate the pages, run Sphinx.

``python docs/_gen/site.py [--out DIR]`` (what ``bash scripts/docs.sh`` runs) writes the HTML
site into ``DIR`` (default ``docs/_build/html``). The sources are staged in a folder beside it
(``DIR/../src``) that mirrors the repository's layout, ``src/docs`` (a copy of ``docs/``) next
to ``src/results``, ``src/CHANGELOG.md`` and ``src/README.md`` (links to the repository's), so
the pages' relative includes (``../results/leaderboard.md``) work in both places and a build
never writes into ``docs/``.

Generated into the staging copy, from the code as it is at build time (nothing here names an
environment id, a controller or a module):

- ``envs/<Name>-vN.md``, one per id of ``cir_gym.ENVIRONMENTS``: the class docstring (markdown
  in Gymnasium's sections), its spaces and episode length from ``gymnasium.make``, the
  controllers (``cir_gym.baselines.available``) and shipped agents
  (``cir_gym.agents.available``) that apply, and its GIF ``docs/gallery/<Name>-vN.gif``;
- ``envs/index.md``: the table of every environment;
- ``controllers/_<family>.md``: for each module of ``cir_gym.baselines``, the table of its
  controllers (name, class, environments, gains and their defaults), included by the
  family's hand-written page ``controllers/<family>.md``;
- ``api/*.md``: the API reference, one page per layer, every module found by ``pkgutil``;
- ``research/_results.md``: the list of the results pages (``results/*/README.md``) and one
  page per results README (``research/results/<name>.md``).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import os
import pkgutil
import re
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"

#: reST roles in the markdown docstrings (``:mod:`x```) → MyST roles (``{py:mod}`x```)
_ROLE = re.compile(r":(?:py:)?(mod|class|func|meth|attr|data|exc|obj):`([^`]+)`")

#: the layers of the package, top to bottom, as the API reference groups them
#: (title, page, modules or package prefixes); the science is every module not named here
LAYERS = [
    ("Command line", "cli", ["cir_gym.cli"]),
    ("Scoring", "scoring", ["cir_gym.scoring"]),
    ("Agents", "agents", ["cir_gym.agents"]),
    ("Controllers", "baselines", ["cir_gym.baselines"]),
    ("Evaluation", "evaluation", ["cir_gym.evaluation"]),
    ("Environments", "envs", ["cir_gym.envs"]),
]


def env_page_name(env_id: str) -> str:
    """'cir_gym/PegInHole-v2' → 'PegInHole-v2' (the page, the GIF and the results' name)."""
    return env_id.split(":")[-1].split("/")[-1]


def myst_roles(text: str) -> str:
    """Rewrite reST roles (``:class:`~x.Y```) into MyST roles (``{py:class}`~x.Y```)."""
    return _ROLE.sub(r"{py:\1}`\2`", text)


def _link_cell(items: list[tuple[str, str]]) -> str:
    return ", ".join(f"[`{text}`]({target})" if target else f"`{text}`" for text, target in items)


def _space(space) -> str:
    """A Gymnasium space in one table cell: a Box as its repr, a Dict as its keys and shapes."""
    spaces = getattr(space, "spaces", None)
    if isinstance(spaces, dict):
        return "`Dict`: " + ", ".join(f"`{k}` {tuple(s.shape)}" for k, s in spaces.items())
    return f"`{space!r}`"


def _family(cls: type) -> str:
    return cls.__module__.rsplit(".", 1)[-1]


def controller_families() -> list[str]:
    """The modules of ``cir_gym.baselines`` that define controllers (not the base module)."""
    from cir_gym import baselines

    return sorted({_family(c) for c in baselines.CONTROLLERS.values()})


def env_pages(out: Path) -> list[str]:
    """Write ``envs/<Name>-vN.md`` for every registered id and ``envs/index.md``."""
    import gymnasium as gym

    import cir_gym
    from cir_gym import agents, baselines

    envs = out / "envs"
    envs.mkdir(parents=True, exist_ok=True)
    names = []
    index_rows = []
    for env_id, (cls, description) in cir_gym.ENVIRONMENTS.items():
        name = env_page_name(env_id)
        names.append(name)
        doc = myst_roles(inspect.getdoc(cls) or "")
        summary, _, body = doc.partition("\n\n")
        env = gym.make(env_id)
        try:
            action, observation = env.action_space, env.observation_space
            steps = env.spec.max_episode_steps if env.spec else None
        finally:
            env.close()
        controllers = [
            (n, f"../controllers/{_family(baselines.controller_class(n, env_id))}.md")
            for n in baselines.available(env_id)
        ]
        trained = agents.available(env_id)
        gif = DOCS / "gallery" / f"{name}.gif"
        lines = [
            f"# {name}",
            "",
            f"{summary.strip()}",
            "",
        ]
        if gif.is_file():
            lines += [
                f"```{{image}} ../gallery/{name}.gif",
                f":alt: {name}: one episode of a reference controller",
                ":width: 360px",
                ":class: env-gif",
                "```",
                "",
            ]
        rows = [
            ("id", f"`{env_id}` (`gymnasium.make(\"{env_id}\")` after `import cir_gym`)"),
            ("class", f"{{py:class}}`{cls.__module__}.{cls.__qualname__}`"),
            ("task", description),
            ("action space", _space(action)),
            ("observation space", _space(observation)),
            ("episode length", f"{steps} steps (`max_episode_steps`)"),
            ("controllers", _link_cell(controllers) or "–"),
            ("trained agents", _link_cell([(a, "") for a in trained]) or "–"),
        ]
        lines += [":::{list-table}", ":class: env-facts", ":widths: 1 5", ""]
        for key, value in rows:
            lines += [f"* - {key}", f"  - {value}"]
        lines += [
            ":::",
            "",
            body.strip(),
            "",
        ]
        (envs / f"{name}.md").write_text("\n".join(lines), encoding="utf-8")
        first = f"[{name}]({name}.md)"
        gif_cell = f"![{name}](../gallery/{name}.gif)" if gif.is_file() else ""
        index_rows.append(
            f"| {first} | {description} | {_link_cell(controllers) or '–'} | {len(trained)} "
            f"| {gif_cell} |"
        )
    index = [
        "# Environments",
        "",
        "Every environment registered by `import cir_gym` (`cir_gym.ENVIRONMENTS`; "
        "`cir-gym list` prints the same list). Each page is generated from the environment "
        "class's docstring, in Gymnasium's sections: description, action and observation "
        "spaces, rewards, starting state, episode end, arguments, metrics, reference "
        "controllers and version history.",
        "",
        "| environment | task | controllers | agents | one episode |",
        "|---|---|---|---|---|",
        *index_rows,
        "",
        "```{toctree}",
        ":hidden:",
        "",
        *names,
        "```",
        "",
    ]
    (envs / "index.md").write_text("\n".join(index), encoding="utf-8")
    return names


def controller_tables(out: Path) -> None:
    """Write ``controllers/_<family>.md``: each family's controllers, environments, gains."""
    import cir_gym
    from cir_gym import baselines

    by_family: dict[str, list[tuple[str, type]]] = {}
    for name in baselines.CONTROLLERS:
        for env_id in cir_gym.ENVIRONMENTS:
            if name in baselines.available(env_id):
                cls = baselines.controller_class(name, env_id)
                entry = (name, cls)
                if entry not in by_family.setdefault(_family(cls), []):
                    by_family[_family(cls)].append(entry)
    folder = out / "controllers"
    folder.mkdir(parents=True, exist_ok=True)
    for family in controller_families():
        lines = [
            "| controller | class | environments | gains (defaults) |",
            "|---|---|---|---|",
        ]
        for name, cls in by_family.get(family, []):
            envs = [
                (env_page_name(e), f"../envs/{env_page_name(e)}.md")
                for e in cir_gym.ENVIRONMENTS
                if name in baselines.available(e) and baselines.controller_class(name, e) is cls
            ]
            gains = ", ".join(
                f"`{f.name}={f.default!r}`" for f in dataclasses.fields(cls.Gains)
            ) or "none"
            lines.append(
                f"| `{name}` | {{py:class}}`~{cls.__module__}.{cls.__qualname__}` | "
                f"{_link_cell(envs)} | {gains} |"
            )
        lines.append("")
        (folder / f"_{family}.md").write_text("\n".join(lines), encoding="utf-8")


def _modules(package: str) -> list[str]:
    module = importlib.import_module(package)
    names = [package]
    if hasattr(module, "__path__"):
        for info in pkgutil.walk_packages(module.__path__, package + "."):
            if not info.name.rsplit(".", 1)[-1].startswith("_"):
                names.append(info.name)
    return names


def api_pages(out: Path) -> None:
    """Write ``api/index.md`` and one page per layer (every module found by ``pkgutil``)."""
    api = out / "api"
    api.mkdir(parents=True, exist_ok=True)
    every = _modules("cir_gym")
    claimed: set[str] = set()
    pages = []
    for title, page, prefixes in LAYERS:
        modules = []
        for prefix in prefixes:
            modules += [m for m in _modules(prefix) if m not in claimed]
        claimed.update(modules)
        pages.append((title, page, modules))
    science = [m for m in every if m not in claimed and m != "cir_gym"]
    pages.append(("Science", "science", ["cir_gym", *science]))
    for title, page, modules in pages:
        lines = [f"# {title}", ""]
        for module in modules:
            lines += [
                f"## `{module}`",
                "",
                "```{eval-rst}",
                f".. automodule:: {module}",
                "```",
                "",
            ]
        (api / f"{page}.md").write_text("\n".join(lines), encoding="utf-8")
    index = [
        "# API reference",
        "",
        "The package's layers, top to bottom: nothing imports a layer above its own "
        "(`tests/test_layers.py` enforces it). The controllers and the evaluation sit side by "
        "side above the environments; the science modules below need only numpy, MuJoCo "
        "and Gymnasium.",
        "",
        "| layer | modules |",
        "|---|---|",
    ]
    for title, page, modules in pages:
        index.append(f"| [{title}]({page}.md) | {', '.join(f'`{m}`' for m in modules)} |")
    index += ["", "```{toctree}", ":hidden:", "", *[p for _, p, _ in pages], "```", ""]
    (api / "index.md").write_text("\n".join(index), encoding="utf-8")


#: repository paths and where the site mounts them (a page's relative links are rewritten
#: from the repository's layout to the site's, so both read the same on GitHub and here)
MOUNTS = {"docs": "", "results": "results", "CHANGELOG.md": "changelog.md"}
#: files of ``results/`` the site takes (pages and the images they show)
RESULT_FILES = {".md", ".png", ".gif", ".jpg", ".jpeg", ".svg"}
#: pages owned elsewhere that the user guide lists when they exist
OPTIONAL_PAGES = ("sweeps", "policies")

_LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s]+)(\))")


def site_path(repo_path: str) -> str | None:
    """The site path of a repository path (``results/x.md`` → ``results/x.md``,
    ``docs/envs/a.md`` → ``envs/a.md``), or None when the site does not hold it."""
    for mount, target in MOUNTS.items():
        if repo_path == mount:
            return target or "."
        if repo_path.startswith(mount + "/"):
            rest = repo_path[len(mount) + 1 :]
            return f"{target}/{rest}" if target else rest
    return None


def held(repo_path: str) -> bool:
    """Whether the site holds a copy of this repository file (:func:`stage` copies it)."""
    path = REPO / repo_path
    if not path.is_file():
        return False
    if repo_path.startswith("results/"):
        return path.suffix.lower() in RESULT_FILES
    return site_path(repo_path) is not None


def rewrite_links(text: str, repo_file: str, site_file: str) -> str:
    """Rewrite the relative markdown links of ``repo_file`` (a repository path) for its copy
    at ``site_file`` (a site path): a target the site holds points to the site's copy; a
    repository file or folder it does not hold becomes its path in code font."""

    def one(match: re.Match) -> str:
        target = match.group(2)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
            return match.group(0)
        path, hash_, anchor = target.partition("#")
        if not path:
            return match.group(0)
        resolved = os.path.normpath(os.path.join(os.path.dirname(repo_file), path))
        resolved = resolved.replace(os.sep, "/")
        mapped = site_path(resolved)
        if mapped is None or not held(resolved):
            if match.group(1).startswith("!") or not (REPO / resolved).exists():
                return match.group(0)  # an image, or a missing file: left for the link check
            # a repository file or folder the site does not hold: its path, in code font
            text = match.group(1)[1:-2]
            return text if text.strip("`") == resolved else f"{text} (`{resolved}`)"
        new = os.path.relpath(mapped, os.path.dirname(site_file) or ".").replace(os.sep, "/")
        if path.endswith("/") and not new.endswith("/"):
            new += "/"
        return f"{match.group(1)}{new}{hash_}{anchor}{match.group(3)}"

    return _LINK.sub(one, text)


def _copy(repo_file: Path, site_root: Path, orphan: bool = False) -> None:
    rel = repo_file.relative_to(REPO).as_posix()
    site_rel = site_path(rel)
    assert site_rel is not None, rel
    dest = site_root / site_rel
    dest.parent.mkdir(parents=True, exist_ok=True)
    if repo_file.suffix == ".md":
        text = rewrite_links(repo_file.read_text(encoding="utf-8"), rel, site_rel)
        if rel.startswith("docs/") and not rel.startswith("docs/research/"):
            text = current_ids(text)
        if orphan and not text.startswith("---"):
            text = "---\norphan: true\n---\n\n" + text
        dest.write_text(text, encoding="utf-8")
    else:
        try:
            os.link(repo_file, dest)
        except OSError:
            shutil.copy2(repo_file, dest)


def stage(src: Path) -> None:
    """Copy ``docs/``, ``results/`` (pages and images) and ``CHANGELOG.md`` into ``src`` at
    their site paths, links rewritten."""
    if src.exists():
        shutil.rmtree(src)
    src.mkdir(parents=True)
    for path in sorted(DOCS.rglob("*")):
        parts = path.relative_to(DOCS).parts
        if path.is_file() and not {"_build", "_gen", "__pycache__"} & set(parts):
            _copy(path, src)
    for path in sorted((REPO / "results").rglob("*")):
        if path.is_file() and path.suffix.lower() in RESULT_FILES:
            _copy(path, src, orphan=True)
    if (REPO / "CHANGELOG.md").is_file():
        _copy(REPO / "CHANGELOG.md", src)
    guide = src / "guide" / "index.md"
    if guide.is_file():
        lines = guide.read_text(encoding="utf-8").splitlines()
        missing = {f"../{p}" for p in OPTIONAL_PAGES if not (src / f"{p}.md").is_file()}
        guide.write_text("\n".join(x for x in lines if x.strip() not in missing) + "\n")


def results_index(src: Path) -> None:
    """Write ``research/_results.md``: every results folder and its pages, as links."""
    lines = ["| folder | pages |", "|---|---|"]
    results = src / "results"
    for folder in sorted(p for p in results.iterdir() if p.is_dir()):
        pages = sorted(folder.rglob("*.md"), key=lambda p: (p.name != "README.md", str(p)))
        if not pages:
            continue
        links = ", ".join(
            f"[{p.relative_to(folder).with_suffix('').as_posix()}]"
            f"(../{p.relative_to(src).as_posix()})"
            for p in pages
        )
        lines.append(f"| `results/{folder.name}/` | {links} |")
    lines.append("")
    (src / "research" / "_results.md").write_text("\n".join(lines), encoding="utf-8")


def cli_help(out: Path) -> None:
    """Write ``guide/_cli_help.md``: ``cir-gym --help`` and each command's ``--help``."""
    import argparse

    from cir_gym.cli import build_parser

    os.environ["COLUMNS"] = "92"  # argparse wraps to the terminal's width
    parser = build_parser()
    lines = ["```text", parser.format_help().rstrip(), "```", ""]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                lines += [f"### `cir-gym {name}`", "", "```text", sub.format_help().rstrip()]
                lines += ["```", ""]
    (out / "guide").mkdir(parents=True, exist_ok=True)
    (out / "guide" / "_cli_help.md").write_text("\n".join(lines), encoding="utf-8")


_ID = re.compile(r"cir_gym/([A-Za-z][A-Za-z0-9]*)-v(\d+)")


def current_ids(text: str) -> str:
    """Rewrite each ``cir_gym/<Name>-vN`` to the registered version of ``<Name>`` (the
    hand-written pages' examples follow a version bump; an unknown name is left alone)."""
    import cir_gym

    registered = {env_page_name(i).rsplit("-v", 1)[0]: i for i in cir_gym.ENVIRONMENTS}
    return _ID.sub(lambda m: registered.get(m.group(1), m.group(0)), text)


def gallery(out: Path) -> None:
    """Write ``_gallery.md``: every registered environment's GIF, linked to its page."""
    import cir_gym

    cells = []
    for env_id in cir_gym.ENVIRONMENTS:
        name = env_page_name(env_id)
        if (out / "gallery" / f"{name}.gif").is_file():
            cells.append(f"[![{name}](gallery/{name}.gif)](envs/{name}.md)")
    lines = ["```{container} gallery", "", " ".join(cells), "```", ""]
    (out / "_gallery.md").write_text("\n".join(lines), encoding="utf-8")


def build(out: Path, staging: Path | None = None, quiet: bool = True) -> int:
    """Stage, generate and build; return Sphinx's exit status (0 on success)."""
    from sphinx.cmd.build import build_main

    staging = staging or out.parent / "src"
    src = staging / "site"
    stage(src)
    env_pages(src)
    controller_tables(src)
    api_pages(src)
    results_index(src)
    cli_help(src)
    gallery(src)
    if (out / ".buildinfo").is_file():  # a previous build: start clean (no stale pages)
        shutil.rmtree(out)
    args = ["-b", "html", "-E", "-d", str(staging / "doctrees"), str(src), str(out)]
    if quiet:
        args.insert(0, "-q")
    return build_main(args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, default=DOCS / "_build" / "html", help="the HTML site's folder"
    )
    parser.add_argument("--verbose", action="store_true", help="Sphinx's progress output")
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    start = time.perf_counter()
    status = build(args.out.resolve(), quiet=not args.verbose)
    index = args.out.resolve() / "index.html"
    if status == 0:
        print(f"docs built in {time.perf_counter() - start:.0f} s: {index}")
    return status


if __name__ == "__main__":
    sys.exit(main())
