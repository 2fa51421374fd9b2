"""A Sphinx extension: the package's docstrings are plain prose, not reStructuredText.

They use ``double backticks`` for code (as RST does), but also ``|x|`` for an absolute value and
indented continuation lines, which RST reads as substitutions and block quotes. Before sphinx-autoapi
renders an object, its docstring is made RST-safe: bars escaped outside literals; a docstring that
still does not parse cleanly keeps its first paragraph as prose (the summary tables read it) and
shows the rest verbatim, as a literal block, so nothing is lost or mis-rendered.
"""

import functools
import re
import textwrap

import docutils.core
import docutils.frontend
import docutils.nodes
import docutils.parsers.rst
import docutils.readers.standalone
import docutils.utils

_LITERAL = re.compile(r"(``.+?``)", re.S)


def escape_bars(text):
    """`text` with every ``|`` outside a ````literal```` escaped (RST would read a substitution)."""
    parts = _LITERAL.split(text)
    return "".join(part if i % 2 else part.replace("|", r"\|") for i, part in enumerate(parts))


@functools.cache
def _quiet_settings():
    """docutils' settings for :func:`parses_cleanly`, made once: building them (an option parser
    per call) was three quarters of each parse, about 40 s of the manual's build."""
    settings = docutils.frontend.get_default_settings(
        docutils.parsers.rst.Parser, docutils.readers.standalone.Reader
    )
    settings.report_level, settings.halt_level, settings.warning_stream = 5, 5, False
    return settings


def parses_cleanly(text):
    """Whether docutils parses `text` as RST without a warning or an error."""
    tree = docutils.core.publish_doctree(text, settings=_quiet_settings())
    messages = tree.findall(docutils.nodes.system_message)
    return not any(m["level"] >= docutils.utils.Reporter.WARNING_LEVEL for m in messages)


@functools.cache
def rst_safe(docstring):
    """The docstring as RST that renders what its author wrote (see the module docstring). Kept
    per text: with ``imported-members`` a function re-exported by its package is an object of each
    module that shows it, with the same docstring."""
    escaped = escape_bars(docstring)
    if parses_cleanly(escaped):
        return summary_on_one_line(escaped)
    text = textwrap.dedent(docstring).strip()
    first_paragraph, _, after = text.partition("\n\n")
    prose = escape_bars(first_paragraph)
    if not parses_cleanly(prose):  # then only the summary line is prose, every RST mark-up escaped
        first_line, _, rest_of_paragraph = text.partition("\n")
        prose = re.sub(r"([\\`*_|])", r"\\\1", first_line)
        after = rest_of_paragraph
    verbatim = textwrap.dedent(after).strip("\n")
    if not verbatim:
        return prose + "\n"
    literal = "\n".join("    " + line if line.strip() else "" for line in verbatim.splitlines())
    return f"{prose}\n\n::\n\n{literal}\n"


def summary_on_one_line(text):
    """`text` with its first paragraph on one line when its first line alone is not clean RST
    (a literal broken across lines): autoapi's summary tables show the first line."""
    first_paragraph, blank, rest = text.strip().partition("\n\n")
    if parses_cleanly(first_paragraph.partition("\n")[0]):
        return text
    return " ".join(first_paragraph.split()) + blank + rest


def _sanitize(app, what, name, obj, skip, options):
    if not getattr(obj, "_plain_docstring_done", False) and obj.docstring:
        obj.docstring = rst_safe(obj.docstring)
        obj._plain_docstring_done = True
    return None  # leaves the decision to skip to autoapi


def setup(app):
    app.connect("autoapi-skip-member", _sanitize)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
