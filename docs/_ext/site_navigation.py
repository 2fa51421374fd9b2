"""A Sphinx extension: the site's navigation tree is resolved once per build, not once per page.

Furo's sidebar shows the whole site (``toctree(collapse=False, titles_only=True, maxdepth=-1,
includehidden=True)`` on every page). Sphinx resolves that tree again for each page, and on the
way deep-copies the full table of contents of every page it lists (an API page's lists every
function and class) only to keep their titles: with 180 pages, 40 % of the manual's build. The
tree differs from page to page in two things only: its links are relative to the page, and the
branch that leads to the page has the class ``current``. Furo then rewrites the tree's HTML on
every page with BeautifulSoup (a checkbox for each branch, checked on the page's own branch, and
``current-page`` on its entry): as long again. So the tree is resolved once, with each link still
naming its document, rendered by Sphinx once and rewritten by Furo once, with a mark (a
private-use character, a letter and a number: no title or link has one) in place of each link and
of each ``current``, ``checked`` and ``current-page`` a page may get; each page's two texts are
these with its own values in place of the marks: the same HTML (tests/test_docs.py builds a small
site both ways and compares every page, and the tree's text with Sphinx's, page by page). Furo's
``get_navigation_tree`` is given, for a page, the text made for it (any other text goes to Furo's
own function); any other ``toctree(...)`` call of a template goes to Sphinx as before.

Since every page shows the tree, a build that read a page again (or lost one) writes every page
again, not only those it read: a title or a page may have changed, and so may a link's target.
"""

import re

import furo
from bs4 import BeautifulSoup
from bs4.formatter import HTMLFormatter
from docutils import nodes
from docutils.writers._html_base import HTMLTranslator
from sphinx.environment.adapters.toctree import global_toctree_for_doc
from sphinx.util import url_re

SITE_TREE = {"collapse": False, "titles_only": True, "maxdepth": -1, "includehidden": True}
NO_PAGE = "\0"  # a document name no page has: the tree resolved for it marks no branch current
MARK = "\ue000"  # a private-use character: with a letter and a number, a mark in the tree's text
LINK = re.compile("\ue000h(\\d+)\ue000")  # a link's target
CLASSES = re.compile(' class="([^"]*\ue000[^"]*)"')  # a class list with marks (c: current, p: current-page)
CHECKED = re.compile(' checked="\ue000k(\\d+)\ue000"')  # Furo's checkbox of a branch
FURO_TREE = furo.get_navigation_tree  # Furo's own rewriting of a tree (BeautifulSoup)
BS4_TEXT = HTMLFormatter.REGISTRY["minimal"]  # how BeautifulSoup writes an attribute's value
WHITESPACE = re.compile("[\n\r\t\v\f]")  # what docutils writes as a space in an attribute


class _LinksByDocname:
    """Stands for the builder while the tree is resolved: each link keeps its document's name."""

    @staticmethod
    def get_relative_uri(from_docname, to_docname, typ=None):
        return to_docname


class PageTree(str):
    """The site tree of one page as Sphinx renders it, with what Furo makes of it (``furo``)."""

    furo = ""


class SiteNavigation:
    """The site tree of one build, rendered once with marks, then for each page with its values."""

    def __init__(self, app):
        builder = app.builder
        self.builder = builder
        tree = global_toctree_for_doc(builder.env, NO_PAGE, _LinksByDocname(), tags=builder.tags, **SITE_TREE)
        self.targets = []  # per link mark: (document name, anchor)
        self.branches = {}  # document name: {branch mark: how many times the page puts current on it}
        self.last_item = {}  # document name: the class mark of its last <li> marked current
        if tree is None:
            self.sphinx = builder.render_partial(None)["fragment"]
            self.furo = FURO_TREE(self.sphinx)
            return
        marks = {}  # node: its class mark (for each node a page may mark current)
        for reference in list(tree.findall(nodes.reference)):
            uri = reference["refuri"]
            if url_re.match(uri) is not None:
                continue
            docname = uri.removesuffix(reference["anchorname"])
            reference["refuri"] = f"{MARK}h{len(self.targets)}{MARK}"
            self.targets.append((docname, reference["anchorname"]))
            if reference["anchorname"]:
                continue
            counts = self.branches.setdefault(docname, {})
            node = reference
            while node:  # as Sphinx's _toctree_add_classes: ``current`` up the branch
                mark = marks.setdefault(node, len(marks))
                counts[mark] = counts.get(mark, 0) + 1
                node = node.parent
        for node, mark in marks.items():
            node["classes"].append(f"{MARK}c{mark}{MARK}")
        items = [marks[item] for item in tree.findall(nodes.list_item) if item in marks]  # document order
        for docname, counts in self.branches.items():
            self.last_item[docname] = next(mark for mark in reversed(items) if mark in counts)
        self.sphinx = builder.render_partial(tree)["fragment"]
        soup = BeautifulSoup(FURO_TREE(self.sphinx), "html.parser")
        for item in soup.find_all("li"):
            mark = next((name for name in item.get("class", []) if name.startswith(f"{MARK}c")), None)
            if mark is None:
                continue
            number = mark.strip(MARK)[1:]
            item["class"].append(f"{MARK}p{number}{MARK}")
            checkbox = item.find("input", class_="toctree-checkbox", recursive=False)
            if checkbox is not None:
                checkbox["checked"] = f"{MARK}k{number}{MARK}"
        self.furo = str(soup)

    def html_for(self, pagename):
        """The tree as ``pagename`` shows it, as Sphinx's ``toctree(**SITE_TREE)`` renders it,
        with what Furo's sidebar makes of it as its ``furo``."""
        counts = self.branches.get(pagename, {})
        current_page = self.last_item.get(pagename)
        uris = [
            WHITESPACE.sub(" ", self.builder.get_relative_uri(pagename, docname) + anchor or "#")
            for docname, anchor in self.targets
        ]  # as Sphinx's writer has them (the link to the page itself: "#")

        def word(name):
            if not name.startswith(MARK):
                return name
            number = int(name[2:-1])
            if name[1] == "c":
                return " ".join(["current"] * counts.get(number, 0))
            return "current-page" if number == current_page else ""

        def class_list(match):
            words = " ".join(filter(None, map(word, match[1].split(" "))))
            return f' class="{words}"' if words else ""

        def fill(text, escape):
            text = CLASSES.sub(class_list, text)
            text = CHECKED.sub(lambda match: ' checked=""' if counts.get(int(match[1])) else "", text)
            return LINK.sub(lambda match: escape(uris[int(match[1])]), text)

        page = PageTree(fill(self.sphinx, lambda uri: uri.translate(HTMLTranslator.special_characters)))
        page.furo = fill(self.furo, BS4_TEXT.attribute_value)
        return page


def _furo_tree(toctree_html):
    """Furo's ``get_navigation_tree``: for a page's tree from :class:`SiteNavigation`, the text
    made for it; for any other text, Furo's own function."""
    if isinstance(toctree_html, PageTree):
        return toctree_html.furo
    return FURO_TREE(toctree_html)


def _note_removed(app, env, added, changed, removed):
    app.site_changed = bool(removed)
    return []


def _note_read(app, env, docnames):
    app.site_changed = app.site_changed or bool(docnames)


def _every_page_when_the_site_changed(app, env):
    """Sphinx writes again only the pages it read again, but every page shows the site tree (and
    may link into a page that changed): when any page was read again or removed, every page is
    written again (the warnings of the writing, missing references, come from all of them)."""
    app.site_navigation = None  # resolved again from this build's environment
    return sorted(env.found_docs) if app.site_changed else []


def _fast_site_tree(app, pagename, templatename, context, doctree):
    """Before the theme reads ``context["toctree"]``: the site tree from :class:`SiteNavigation`."""
    sphinx_toctree = context.get("toctree")
    if sphinx_toctree is None:
        return

    def toctree(**kwargs):
        if kwargs != SITE_TREE:
            return sphinx_toctree(**kwargs)
        if getattr(app, "site_navigation", None) is None:
            app.site_navigation = SiteNavigation(app)
        return app.site_navigation.html_for(pagename)

    context["toctree"] = toctree


def setup(app):
    app.connect("env-get-outdated", _note_removed)
    app.connect("env-before-read-docs", _note_read)
    app.connect("env-updated", _every_page_when_the_site_changed)
    app.connect("html-page-context", _fast_site_tree, priority=400)  # Furo's handler: 500
    furo.get_navigation_tree = _furo_tree  # what Furo's handler calls (other texts: Furo's own)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
