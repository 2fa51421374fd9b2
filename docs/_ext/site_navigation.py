"""A Sphinx extension: the site's navigation tree is resolved once per build, not once per page.

Furo's sidebar shows the whole site (``toctree(collapse=False, titles_only=True, maxdepth=-1,
includehidden=True)`` on every page). Sphinx resolves that tree again for each page, and on the
way deep-copies the full table of contents of every page it lists (an API page's lists every
function and class) only to keep their titles: with 180 pages, 40 % of the manual's build. The
tree differs from page to page in two things only: its links are relative to the page, and the
branch that leads to the page has the class ``current``. So it is resolved once, with each link
still naming its document, and each page gets a copy with its own links and ``current`` branch,
rendered as Sphinx renders it: the same HTML (tests/test_docs.py builds a small site both ways
and compares every page). Any other ``toctree(...)`` call of a template goes to Sphinx as before.

Since every page shows the tree, a build that read a page again (or lost one) writes every page
again, not only those it read: a title or a page may have changed, and so may a link's target.
"""

from docutils import nodes
from sphinx.environment.adapters.toctree import global_toctree_for_doc
from sphinx.util import url_re

SITE_TREE = {"collapse": False, "titles_only": True, "maxdepth": -1, "includehidden": True}
NO_PAGE = "\0"  # a document name no page has: the tree resolved for it marks no branch current


class _LinksByDocname:
    """Stands for the builder while the tree is resolved: each link keeps its document's name."""

    @staticmethod
    def get_relative_uri(from_docname, to_docname, typ=None):
        return to_docname


class SiteNavigation:
    """The site tree of one build: its nodes with links by document name, and those names."""

    def __init__(self, app):
        builder = app.builder
        self.builder = builder
        self.tree = global_toctree_for_doc(
            builder.env, NO_PAGE, _LinksByDocname(), tags=builder.tags, **SITE_TREE
        )  # fmt: skip
        self.docnames = []  # per reference node, in document order; None for an external link
        if self.tree is not None:
            for reference in self.tree.findall(nodes.reference):
                uri = reference["refuri"]
                external = url_re.match(uri) is not None
                self.docnames.append(None if external else uri.removesuffix(reference["anchorname"]))

    def html_for(self, pagename):
        """The tree as ``pagename`` shows it, as Sphinx's ``toctree(**SITE_TREE)`` renders it."""
        if self.tree is None:
            return self.builder.render_partial(None)["fragment"]
        tree = self.tree.deepcopy()
        for reference, docname in zip(tree.findall(nodes.reference), self.docnames, strict=True):
            if docname is None:
                continue
            if docname == pagename:
                _mark_current(reference)
            reference["refuri"] = self.builder.get_relative_uri(pagename, docname) + reference["anchorname"]
        return self.builder.render_partial(tree)["fragment"]


def _mark_current(reference):
    """What Sphinx's ``_toctree_add_classes`` does for the link to the page itself: the class
    ``current`` up its branch (a link to a section of the page: not), ``iscurrent`` likewise."""
    if not reference["anchorname"]:
        node = reference
        while node:
            node["classes"].append("current")
            node = node.parent
    if reference.parent.parent.get("iscurrent"):
        return
    node = reference
    while node:
        node["iscurrent"] = True
        node = node.parent


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
    return {"parallel_read_safe": True, "parallel_write_safe": True}
