"""The manual (docs/, built by ``make docs``): what its pages must say, every internal link of the
built site, and the built pages read in a headless Chromium (the API page shows a known
function, a notebook page shows its figure, the scenario table has a row per bundled scenario).

The built-site tests read docs/_build/html, building it first (``sphinx-build -W``, as ``make docs``
does) when a page, notebook or module is newer than the built site: CI runs ``make docs`` just
before the tests, so there they read that build; elsewhere a broken page, link or notebook fails
here as it fails the build."""

import importlib
import io
import re
import shutil
import subprocess
import sys
import time
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from test_meshcat_animation import DevTools

from quad_drake import cli
from quad_drake.config import CRITERION_KINDS
from quad_drake.running import catalog
from quad_drake.running.simulation import run

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
HTML = DOCS / "_build" / "html"
PAGES = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts)
RESULTS_TABLE = re.compile(r"<!-- results-table -->\n(.*?)<!-- /results-table -->", re.S)


def test_the_readme_is_a_front_door_of_at_most_300_lines():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 300
    for target in ("docs/getting-started.md", "docs/guide/01_run.md", "docs/reference/scenarios.md"):
        assert f"]({target})" in readme and (ROOT / target).is_file(), target
    assert "make run" in readme and "make test" in readme and "](docs/11_estimate_errors.png)" in readme


def test_the_scenario_reference_has_one_row_per_bundled_scenario_with_its_criteria():
    # The criteria column counts what a run of the scenario judges today (its own criteria and the
    # flight-safety ones of each vehicle): a criterion added to every scenario shows here.
    from quad_drake.judging.evaluation import judged_criteria

    page = (DOCS / "reference" / "scenarios.md").read_text(encoding="utf-8")
    rows = [
        [c.strip() for c in line.split("|")[1:-1]]
        for line in RESULTS_TABLE.search(page).group(1).splitlines()[2:]
    ]
    assert [row[0] for row in rows] == list(catalog.bundled_scenarios())
    for name, _, criteria, result, *_ in rows:
        judged = len(judged_criteria(catalog.load(name)))
        assert (criteria, result) == (f"{judged}/{judged}", "PASS"), name


def test_the_criteria_reference_has_a_row_per_criterion_kind():
    page = (DOCS / "reference" / "criteria.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \|", page.split("## Flight-safety criteria")[0], flags=re.M)
    assert rows == list(CRITERION_KINDS)


@pytest.mark.parametrize("page", sorted((DOCS / "measurements").glob("*.md")), ids=lambda p: p.stem)
def test_a_measurement_page_says_when_and_how_it_was_measured(page):
    text = page.read_text(encoding="utf-8")
    assert re.search(r"\b20\d\d-\d\d-\d\d\b", text), "no date"
    assert re.search(r"`(quad-drake |python |nice )[^`]*`|```bash", text), "no command"


def test_every_module_path_the_manual_names_exists():
    # Paths of the package's files (quad_drake/x.py, or sub/x.py of one of its subpackages) in the
    # README and the manual's pages; the measurement pages are dated records and may name a module
    # as it was then.
    package = ROOT / "quad_drake"
    subpackages = {p.name for p in package.iterdir() if (p / "__init__.py").is_file()}
    missing = []
    for page in [ROOT / "README.md", *PAGES]:
        if "measurements" in page.parts:
            continue
        text = page.read_text(encoding="utf-8")
        paths = re.findall(r"\bquad_drake/([\w/]+\.py)", text)
        paths += [path for path, first in re.findall(r"`((\w+)/[\w/]*\.py)`", text) if first in subpackages]
        for path in paths:
            if not (package / path).is_file():
                missing.append(f"{page.relative_to(ROOT)}: {path}")
    assert missing == []


def test_no_page_cites_an_issue_number_a_reader_cannot_resolve():
    for page in [ROOT / "README.md", *PAGES]:
        cited = re.findall(r"\bissues? \d+", page.read_text(encoding="utf-8"), flags=re.I)
        assert cited == [], f"{page.relative_to(ROOT)}: {cited}"


def docs_extension(name):
    """The Sphinx extension docs/_ext/`name`.py, imported."""
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(DOCS / "_ext"))


def test_a_docstring_is_made_rst_safe_the_same_way_call_after_call():
    """docs/_ext/plain_docstrings.py parses every docstring of the package (thousands per build)
    with one set of docutils settings: a warning in one parse must not leak into the next."""
    pytest.importorskip("docutils", reason="the docs extra is missing (pip install -e '.[docs]')")
    plain_docstrings = docs_extension("plain_docstrings")
    for _ in range(2):
        assert not plain_docstrings.parses_cleanly("an *unclosed emphasis")
        assert not plain_docstrings.parses_cleanly("a line\n  indented\nunindented")  # a quote cut short
        assert plain_docstrings.parses_cleanly("plain prose with ``code``")
    assert plain_docstrings.rst_safe("The norm |v| of ``a|b``.") == "The norm \\|v\\| of ``a|b``."
    broken = "Summary with *one star.\n\n  indented rest\n"
    assert plain_docstrings.rst_safe(broken) == "Summary with \\*one star.\n\n::\n\n    indented rest\n"


SMALL_SITE = {
    "index.rst": "Home\n====\n\n.. toctree::\n   :caption: Guide\n\n   guide/run\n   guide/deep/page\n"
    "   guide/r&d\n   Outside <https://example.org>\n\n.. toctree::\n   :hidden:\n\n   api/index\n",
    "guide/run.rst": "Run\n===\n\nA section\n---------\n\nText.\n\nAnother\n-------\n\nText.\n",
    "guide/deep/page.rst": "Deep page\n=========\n\nText.\n\nSecond title\n============\n\nText.\n",
    "guide/r&d.rst": "R&D <notes>\n============\n\nText.\n",
    "api/index.rst": "API\n===\n\n.. toctree::\n\n   mod/index\n   ../guide/run\n",
    "api/mod/index.rst": "A module\n========\n\nFunctions\n---------\n\n.. py:function:: f(x)\n\n   Text.\n",
}


def test_the_site_tree_resolved_once_renders_every_page_as_sphinx_does(tmp_path):
    """docs/_ext/site_navigation.py resolves the sidebar's site tree, and Furo's rewriting of it,
    once per build: a small site (captions, a hidden toctree, an external link, pages two folders
    deep, a page listed twice, a page with two titles, a name and a title to escape) built with it
    and without it gives the same bytes on every page."""
    pytest.importorskip("furo", reason="the docs extra is missing (pip install -e '.[docs]')")
    from sphinx.testing.util import SphinxTestApp

    site_navigation = docs_extension("site_navigation")

    for name, text in SMALL_SITE.items():
        (tmp_path / "src" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "src" / name).write_text(text, encoding="utf-8")
    built = {}
    for extensions in ([], ["site_navigation"]):
        conf = f"extensions = {extensions!r}\nhtml_theme = 'furo'\n"
        (tmp_path / "src" / "conf.py").write_text(conf, encoding="utf-8")
        warnings = io.StringIO()
        build = tmp_path / f"build{len(extensions)}"
        app = SphinxTestApp(srcdir=tmp_path / "src", builddir=build, warning=warnings)
        try:
            app.build()
            if extensions:  # the text a template's toctree() gets: Sphinx's own, page by page
                for docname in sorted(app.env.found_docs):
                    sphinx_tree = app.builder._get_local_toctree(docname, **site_navigation.SITE_TREE)
                    assert app.site_navigation.html_for(docname) == sphinx_tree, docname
        finally:
            app.cleanup()  # docutils' global registrations, for the next build in this process
        assert app.statuscode == 0 and warnings.getvalue() == ""
        built[len(extensions)] = {p.relative_to(app.outdir): p.read_bytes() for p in build.rglob("*.html")}
    assert isinstance(app.site_navigation, site_navigation.SiteNavigation)  # the second build used it
    assert app.site_navigation.furo.count("toctree-checkbox") > 0  # ... and its Furo text
    assert {Path(name).with_suffix(".html") for name in SMALL_SITE} < built[1].keys() == built[0].keys()
    for page, html in built[0].items():
        assert built[1][page] == html, page
    assert b'class="toctree-l2 current current-page"' in built[1][Path("api/mod/index.html")]


class _Links(HTMLParser):
    """The ids and the link targets (href, src) of one HTML page."""

    def __init__(self):
        super().__init__()
        self.ids, self.targets = set(), []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if attrs.get("id"):
            self.ids.add(attrs["id"])
        for key in ("href", "src"):
            if attrs.get(key) and not (tag == "link" and attrs.get("rel") == "canonical"):
                self.targets.append(attrs[key])


def newest_source_time():
    """The newest modification time of what the manual is built from (pages, notebooks, package)."""
    generated = {"_build", "gallery", "api"}  # what the build writes under docs/
    sources = [p for p in DOCS.rglob("*") if not generated & set(p.relative_to(DOCS).parts)]
    sources += [*(ROOT / "notebooks").glob("*.ipynb"), *(ROOT / "quad_drake").rglob("*.py")]
    return max(p.stat().st_mtime for p in sources if p.is_file())


@pytest.fixture(scope="module")
def built_manual():
    """docs/_build/html, built by ``sphinx-build -W`` (as ``make docs``) unless its last build is
    newer than every source (CI runs ``make docs`` just before the tests). Sphinx builds on its
    previous build there: it reads again the pages whose source changed and writes every page
    again (docs/_ext/site_navigation.py). A failed build leaves no previous build behind, so the
    next one reads every page again and repeats every warning."""
    pytest.importorskip("sphinx", reason="the docs extra is missing (pip install -e '.[docs]')")
    last_build = HTML / ".buildinfo"  # Sphinx writes it at the end of each build
    if last_build.is_file() and last_build.stat().st_mtime > newest_source_time():
        return HTML
    build = subprocess.run(
        [sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q", str(DOCS), str(HTML)],
        cwd=ROOT, capture_output=True, text=True,
    )  # fmt: skip
    if build.returncode != 0:
        last_build.unlink(missing_ok=True)
        shutil.rmtree(HTML / ".doctrees", ignore_errors=True)  # Sphinx's environment: read it all again
    assert build.returncode == 0, build.stderr[-4000:]
    return HTML


@pytest.mark.slow
def test_every_internal_link_of_the_built_manual_resolves(built_manual):
    pages = sorted(built_manual.rglob("*.html"))
    parsed = {}
    for page in pages:
        parsed[page] = _Links()
        parsed[page].feed(page.read_text(encoding="utf-8"))
    broken, external = [], set()
    for page, links in parsed.items():
        for target in links.targets:
            url = urlsplit(target)
            if url.scheme in ("http", "https", "mailto"):
                external.add(target)  # listed, not fetched: CI has no internet
                continue
            if url.scheme == "data" or target == "#":
                continue
            path = (page.parent / unquote(url.path)).resolve() if url.path else page
            if path.is_dir():
                path = path / "index.html"
            if not path.is_file():
                broken.append(f"{page.relative_to(built_manual)}: {target}")
            elif url.fragment and path.suffix == ".html":
                if path not in parsed:
                    parsed[path] = _Links()
                    parsed[path].feed(path.read_text(encoding="utf-8"))
                if unquote(url.fragment) not in parsed[path].ids:
                    broken.append(f"{page.relative_to(built_manual)}: {target} (no such anchor)")
    assert len(pages) > 50  # the guide, reference, measurements, notebooks and the API pages
    assert broken == []
    print(f"{len(external)} external links (not fetched):", *sorted(external), sep="\n  ")


PROBE = """(() => {
  const rows = [...document.querySelectorAll("table tbody tr")].map(r => r.cells[0].innerText.trim());
  const images = [...document.querySelectorAll("img")].map(i => ({src: i.src, width: i.naturalWidth}));
  const target = document.getElementById(%r);
  return {title: document.title, rows, images, text: document.body.innerText,
          target: target ? target.closest("dl").innerText : null};
})()"""


@pytest.mark.browser
@pytest.mark.slow
def test_the_built_manual_renders_in_headless_chromium(built_manual, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium not installed (apt-get install chromium; .ci/run installs it)")
    api_page = built_manual / "api" / run.__module__.replace(".", "/") / "index.html"
    run_id = f"{run.__module__}.run"
    pages = {
        "api": (api_page, run_id),
        "scenarios": (built_manual / "reference" / "scenarios.html", ""),
        "notebook": (built_manual / "gallery" / "01_walkthrough.html", ""),
        "cli": (built_manual / "reference" / "cli.html", ""),
    }
    browser = DevTools(chromium, tmp_path / "profile")
    seen = {}
    try:
        target = next(t for t in browser.call("Target.getTargets")["targetInfos"] if t["type"] == "page")
        session = browser.call("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})[
            "sessionId"
        ]
        for domain in ("Network", "Page", "Runtime"):
            browser.call(f"{domain}.enable", session=session)
        for name, (path, element_id) in pages.items():
            browser.events.clear()
            browser.call("Page.navigate", {"url": path.as_uri()}, session=session)
            browser.wait_for("Page.loadEventFired")
            time.sleep(0.3)  # images decode after the load event on a busy machine
            seen[name] = browser.call(
                "Runtime.evaluate", {"expression": PROBE % element_id, "returnByValue": True}, session=session
            )["result"]["value"]
            seen[name]["errors"] = [e for e in browser.events if e.get("method") == "Runtime.exceptionThrown"]
            requests = [e for e in browser.events if e.get("method") == "Network.requestWillBeSent"]
            seen[name]["requests"] = [e["params"]["request"]["url"] for e in requests]
    finally:
        browser.close()

    for name, page in seen.items():
        assert page["errors"] == [], name
        assert [u for u in page["requests"] if not u.startswith(("file:", "data:", "blob:"))] == [], name
    # The API reference shows simulation.run with its signature and its docstring's summary.
    assert seen["api"]["target"] is not None and "run(" in seen["api"]["target"]
    assert " ".join(run.__doc__.split()[:4]) in seen["api"]["target"]  # its docstring's first words
    # The scenario reference: a row per bundled scenario (27 when this was written).
    assert [r for r in seen["scenarios"]["rows"] if r in catalog.bundled_scenarios()] == list(
        catalog.bundled_scenarios()
    )
    # The walkthrough notebook was executed at build: its figures are there and decoded.
    figures = [i for i in seen["notebook"]["images"] if i["width"] > 100]
    assert figures, seen["notebook"]["images"]
    # The CLI reference, generated from the parser, names every sub-command.
    commands = cli.build_parser()._subparsers._group_actions[0].choices
    assert all(command in seen["cli"]["text"] for command in commands), sorted(commands)


def test_make_docs_sets_up_its_tools_and_builds_with_warnings_as_errors(tmp_path):
    venv = tmp_path / "venv"  # not there: make prints every step it would take
    dry = subprocess.run(["make", "-n", "docs", f"VENV={venv}"], cwd=ROOT, capture_output=True, text=True)
    assert dry.returncode == 0, dry.stderr
    assert "pip install -q -e '.[docs]'" in dry.stdout
    assert f"{venv}/bin/python -m sphinx -b html -W --keep-going -q docs docs/_build/html" in dry.stdout
    assert "make docs" in (ROOT / ".ci" / "run").read_text()
