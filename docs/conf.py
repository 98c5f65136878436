"""Sphinx configuration of the cir_gym documentation site.

Build it with ``bash scripts/docs.sh`` (into ``docs/_build/html/``): that script runs
``docs/_gen/site.py``, which copies these sources into a staging folder, writes the generated
pages there (one per registered environment, the controller tables, the API reference) and
runs Sphinx on the copy, so a build never writes into ``docs/`` itself.
"""

from __future__ import annotations

import inspect
import os
import re

os.environ.setdefault("MUJOCO_GL", "egl")

project = "cir_gym"
author = "cir_gym contributors"
copyright = "cir_gym contributors"

try:
    import cir_gym

    release = cir_gym.__version__
except ImportError:  # pragma: no cover - the build script checks the import first
    release = ""

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_gen", "_*.md", "**/_*.md", "Thumbs.db", ".DS_Store"]

# MyST: ``:::`` fences, definition lists, anchors on headings down to level 3 (the Gymnasium
# sections of an environment page: ``envs/PegInHole-v2.html#rewards``).
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# autodoc: members in source order, the signature's type hints in the description.
autodoc_default_options = {
    "members": True,
    "member-order": "bysource",
    "show-inheritance": True,
    "ignore-module-all": True,  # a package's re-exports are documented where they are defined
}
autodoc_typehints = "description"
# a method without a docstring of its own (an env's step) is not given Gymnasium's
autodoc_inherit_docstrings = False
# functions and classes are not entries of the navigation (hundreds of them: slow, and noise)
toc_object_entries = False
autodoc_mock_imports: list[str] = []
napoleon_google_docstring = True
napoleon_numpy_docstring = False
# a class docstring's "Attributes:" as fields, not a second description of each attribute
napoleon_use_ivar = True

html_theme = "furo"
html_title = f"cir_gym {release}"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_show_sourcelink = False
html_copy_source = False
# no web fonts, no CDN: the site reads offline (MathJax is not used: formulas are Unicode)
html_theme_options = {"navigation_with_keys": True}

suppress_warnings = ["myst.header"]
# "torque" stays "torque" (argument values, code in prose): no typographic quotes
smartquotes = False


def _env_classes() -> dict[type, str]:
    """{environment class: its page name} for every registered id (the API reference links
    an environment class to its page instead of repeating its markdown docstring)."""
    try:
        from cir_gym import ENVIRONMENTS
    except ImportError:  # pragma: no cover
        return {}
    pages: dict[type, str] = {}
    for env_id, (cls, _) in ENVIRONMENTS.items():
        pages.setdefault(cls, env_id.split("/")[-1])
    return pages


_ENV_PAGES = _env_classes()


def _env_docstring_to_link(app, what, name, obj, options, lines) -> None:
    """An environment class's docstring is markdown in Gymnasium's sections: it is its own
    page (``envs/<Name>-vN``); here the API reference shows its first line and the link."""
    if what == "class" and inspect.isclass(obj) and obj in _ENV_PAGES:
        first = lines[0] if lines else ""
        lines[:] = [first, "", f"The environment's page: :doc:`/envs/{_ENV_PAGES[obj]}`.", ""]


_LITERAL = re.compile(r"(``.+?``)")


def _escape_bars(app, what, name, obj, options, lines) -> None:
    """The docstrings write norms and absolute values as ``|x|``, which reST reads as a
    substitution: escape every bar outside inline literals (no docstring uses substitutions
    or reST tables), and the star of a path glob (``dir/*.yml``), which reST reads as
    emphasis."""
    for i, line in enumerate(lines):
        if "|" in line or "/*" in line:
            parts = _LITERAL.split(line)
            lines[i] = "".join(p if p.startswith("``") else _escape(p) for p in parts)


def _escape(text: str) -> str:
    return text.replace("|", r"\|").replace("/*", r"/\*")


def setup(app):
    app.connect("autodoc-process-docstring", _env_docstring_to_link)
    app.connect("autodoc-process-docstring", _escape_bars)
    return {"parallel_read_safe": True}
