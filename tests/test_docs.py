"""The documentation site (``bash scripts/docs.sh``) and the README.

One build of the site into a temporary folder (module fixture, ~40 s of CPU) serves the tests:
every registered environment and every controller family has its page, every internal link
and image resolves (``#anchors`` included), and the front page renders in Debian's headless
Chromium. ``bash scripts/test.sh`` installs ``chromium`` when it is missing; run directly
without it, the browser test skips with that message, except under CI (``CI=true``), where a
missing browser fails. Also: the README and the user pages carry no work history ("round N",
"issue N": that is the CHANGELOG's and the research logs' business), the README's links resolve
and its ids are the registered ones, and its layer table names every module of the package.
"""

from __future__ import annotations

import os
import re
import subprocess
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

import cir_gym
from cir_gym import baselines

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
#: the flags of tests/test_leaderboard_page.py: no sandbox as root, no GPU, no network traffic
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
#: the Gymnasium sections every environment page shows (from the class docstring)
SECTIONS = [
    "Description",
    "Action Space",
    "Observation Space",
    "Rewards",
    "Starting State",
    "Episode End",
    "Arguments",
    "Metrics",
    "Reference controllers",
    "Version History",
]
#: work history in a user page: "round 3", "the twelfth round", "issue 21", "issue #21"
ORDINALS = (
    "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|"
    "thirteenth|fourteenth|fifteenth|\\d+(?:st|nd|rd|th)"
)
HISTORY = re.compile(rf"\b(?:round\s+\d+|(?:{ORDINALS})\s+round|issue\s+#?\d+)\b", re.IGNORECASE)


def page_name(env_id: str) -> str:
    return env_id.split("/")[-1]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site built by ``bash scripts/docs.sh --out <tmp>/html``."""
    out = tmp_path_factory.mktemp("docs") / "html"
    done = subprocess.run(
        ["bash", str(REPO / "scripts" / "docs.sh"), "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, (done.stdout + done.stderr)[-4000:]
    assert (out / "index.html").is_file()
    return out


class _Refs(HTMLParser):
    """The ``href``/``src`` of a page and its element ids."""

    def __init__(self) -> None:
        super().__init__()
        self.refs: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for key, value in attrs:
            if value is None:
                continue
            if key in ("href", "src"):
                self.refs.append(value)
            elif key == "id" or (key == "name" and tag == "a"):
                self.ids.add(value)


def _parse(path: Path, cache: dict[Path, _Refs]) -> _Refs:
    if path not in cache:
        parser = _Refs()
        parser.feed(path.read_text(encoding="utf-8", errors="replace"))
        cache[path] = parser
    return cache[path]


def _text(path: Path) -> str:
    """A page's text: the main article (Furo's ``<article>``) without tags or scripts."""
    html = path.read_text(encoding="utf-8")
    article = re.search(r"<article[^>]*>(.*)</article>", html, re.S)
    body = article.group(1) if article else html
    body = re.sub(r"<script.*?</script>", " ", body, flags=re.S)
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", body))


def test_every_registered_environment_has_its_page(site: Path) -> None:
    assert len(cir_gym.ENVIRONMENTS) >= 1
    index = (site / "envs" / "index.html").read_text(encoding="utf-8")
    for env_id in cir_gym.ENVIRONMENTS:
        name = page_name(env_id)
        page = site / "envs" / f"{name}.html"
        assert page.is_file(), f"no page for {env_id}"
        assert f'href="{name}.html"' in index, f"{env_id} missing from envs/index.html"
        text = _text(page)
        assert env_id in text
        missing = [s for s in SECTIONS if f">{s}<" not in page.read_text(encoding="utf-8")]
        assert not missing, f"{env_id}: no section {missing}"
        for controller in baselines.available(env_id):
            assert controller in text, f"{env_id}: controller {controller} not listed"
        if (REPO / "docs" / "gallery" / f"{name}.gif").is_file():
            assert re.search(rf'<img[^>]+src="[^"]*{re.escape(name)}\.gif"', page.read_text())
    stale = {p.stem for p in (site / "envs").glob("*.html")} - {"index"}
    assert stale == {page_name(i) for i in cir_gym.ENVIRONMENTS}


def test_every_controller_family_has_its_page_with_its_course_section(site: Path) -> None:
    families: dict[str, list[str]] = {}
    for name, cls in baselines.CONTROLLERS.items():
        families.setdefault(cls.__module__.rsplit(".", 1)[-1], []).append(name)
    for family, names in families.items():
        page = site / "controllers" / f"{family}.html"
        assert page.is_file(), f"no page for the controller family {family}"
        text = _text(page)
        assert re.search(r"§\s?\d+(\.\d+)*", text), f"{family}: no course section cited"
        for name in names:
            assert name in text, f"{family}: controller {name} not on its page"


def test_the_leaderboard_api_research_and_changelog_are_in_the_site(site: Path) -> None:
    assert "leaderboard" in _text(site / "results" / "leaderboard.html").lower()
    assert (site / "research" / "agents.html").is_file()
    assert "Changelog" in _text(site / "changelog.html")
    api = {p.stem for p in (site / "api").glob("*.html")}
    assert {"science", "envs", "evaluation", "baselines", "agents", "scoring"} <= api
    assert "cir_gym.evaluation.evaluate" in (site / "api" / "evaluation.html").read_text()


def test_every_internal_link_and_image_resolves(site: Path) -> None:
    cache: dict[Path, _Refs] = {}
    broken = []
    pages = sorted(site.rglob("*.html"))
    assert len(pages) > 20
    for page in pages:
        for ref in _parse(page, cache).refs:
            parts = urlsplit(ref)
            if parts.scheme or ref.startswith(("//", "mailto:", "javascript:", "data:")):
                continue
            path = unquote(parts.path)
            target = (page.parent / path).resolve() if path else page
            if site.resolve() not in target.parents and target != site.resolve():
                broken.append(f"{page.relative_to(site)}: {ref} leaves the site")
                continue
            if target.is_dir():
                target = target / "index.html"
            if not target.is_file():
                broken.append(f"{page.relative_to(site)}: {ref}")
            elif parts.fragment and target.suffix == ".html":
                if unquote(parts.fragment) not in _parse(target, cache).ids:
                    broken.append(f"{page.relative_to(site)}: {ref} (no such anchor)")
    assert not broken, "\n".join(broken[:40])


def _need_chromium() -> None:
    if Path(CHROMIUM).exists():
        return
    message = (
        f"Debian's chromium is not installed ({CHROMIUM}): `apt-get install chromium`, or run "
        "`bash scripts/test.sh`, which installs it"
    )
    if os.environ.get("CI", "").lower() == "true":  # CI installs it: missing is a failure
        pytest.fail(message)
    pytest.skip(message)


def _chromium(*args: str, user_dir: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [CHROMIUM, *FLAGS, f"--user-data-dir={user_dir}", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_the_front_page_renders_in_headless_chromium(site: Path, tmp_path: Path) -> None:
    """index.html in Chromium: its DOM has the title, the navigation and every environment's
    link, and a 1366x768 screenshot is drawn (not blank: many colours, dark text on light)."""
    _need_chromium()
    from PIL import Image

    index = site / "index.html"
    dom = _chromium(
        "--virtual-time-budget=5000", "--dump-dom", index.as_uri(), user_dir=tmp_path / "dom"
    )
    assert dom.returncode == 0, dom.stderr[-2000:]
    title = re.search(r"<title>(.*?)</title>", dom.stdout, re.S)
    assert title and "cir_gym" in title.group(1)
    assert 'class="sidebar-tree"' in dom.stdout  # Furo drew its navigation
    for env_id in cir_gym.ENVIRONMENTS:
        assert f'envs/{page_name(env_id)}.html"' in dom.stdout

    shot = tmp_path / "index.png"
    done = _chromium(
        "--window-size=1366,768",
        "--hide-scrollbars",
        "--virtual-time-budget=5000",
        f"--screenshot={shot}",
        index.as_uri(),
        user_dir=tmp_path / "shot",
    )
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    image = Image.open(shot).convert("RGB")
    assert image.size == (1366, 768)
    colours = image.getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 200, "a blank or nearly blank screenshot"
    dark = sum(n for n, (r, g, b) in colours if r + g + b < 150)
    assert dark > 500, "no text drawn"


def _user_pages(site: Path) -> list[Path]:
    """The built pages a user reads as documentation: everything but the research logs and
    the measurement pages of results/ (the leaderboard is a user page)."""
    pages = []
    for page in site.rglob("*.html"):
        rel = page.relative_to(site).as_posix()
        if rel.startswith(("research/", "_")) or rel in ("genindex.html", "search.html"):
            continue
        if rel.startswith("results/") and rel != "results/leaderboard.html":
            continue
        pages.append(page)
    return pages


def test_the_user_pages_carry_no_work_history(site: Path) -> None:
    """No "round N" / "the twelfth round" / "issue N" in the README, the changelog, the
    hand-written pages or any built user page (environment pages, API reference: the
    docstrings), only in the research logs."""
    sources = [REPO / "README.md", REPO / "CHANGELOG.md"] + [
        p
        for p in (REPO / "docs").rglob("*.md")
        if not {"research", "_build"} & set(p.relative_to(REPO / "docs").parts)
    ]
    found = []
    for path in sources:
        for m in HISTORY.finditer(path.read_text(encoding="utf-8")):
            found.append(f"{path.relative_to(REPO)}: {m.group(0)!r}")
    for page in _user_pages(site):
        for m in HISTORY.finditer(_text(page)):
            found.append(f"{page.relative_to(site)} (built): {m.group(0)!r}")
    assert not found, "\n".join(found)


def test_the_history_pattern_finds_history_and_not_round_holes() -> None:
    for history in ("the twelfth round", "Issue 21 made step cheaper", "round 3", "issue #7"):
        assert HISTORY.search(history), history
    for fine in ("a round hole", "round(x, 3)", "round-off", "the issue is the contact"):
        assert not HISTORY.search(fine), fine


def test_the_readme_is_a_front_page_whose_links_and_ids_hold() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 230
    for command in ("bash scripts/run.sh", "bash scripts/test.sh"):
        assert command in text
    missing = []
    targets = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'(?:src|href)="([^"]+)"', text)
    for target in targets:
        if urlsplit(target).scheme or target.startswith("#"):
            continue
        if not (REPO / unquote(urlsplit(target).path)).exists():
            missing.append(target)
    assert not missing, f"README links to missing files: {missing}"
    ids = set(re.findall(r"cir_gym/[A-Za-z][A-Za-z0-9]*-v\d+", text))
    assert ids, "the README names no environment"
    assert ids <= set(cir_gym.ENVIRONMENTS), f"not registered: {ids - set(cir_gym.ENVIRONMENTS)}"
    assert set(cir_gym.ENVIRONMENTS) <= ids, "an environment is missing from the README"


def test_the_readme_layer_table_names_every_module() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    table = text[text.index("## Layers") :]
    package = REPO / "cir_gym"
    modules = [p.name for p in package.glob("*.py") if p.name != "__init__.py"]
    folders = [f"{p.name}/" for p in package.iterdir() if (p / "__init__.py").is_file()]
    missing = [m for m in modules + folders if m not in table]
    assert not missing, f"modules missing from the README's layer table: {missing}"


def test_the_readme_quick_start_runs() -> None:
    """The README's quick start (the user guide's, in one block) runs as written."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    code = re.search(r"## Quick start\n\n```python\n(.*?)```", text, re.S)
    assert code, "no python block under '## Quick start'"
    namespace: dict = {}
    exec(compile(code.group(1), "README.md quick start", "exec"), namespace)
    assert 0.0 <= namespace["result"].success_rate <= 1.0
    assert namespace["result"].summary["rms_error"]["mean"] > 0.0
