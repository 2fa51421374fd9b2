"""The one kind of error a user's configuration raises, and the hint it carries.

Pure (the standard library only): every module that only refuses bad input imports
:class:`ConfigError` from here, so importing it loads neither pydrake nor the schema.
"""


class ConfigError(ValueError):
    """A user mistake in a scenario or an override; str() is one line."""


def did_you_mean(word, choices) -> str:
    """`` (did you mean 'x'?)`` naming the choices closest to `word` (stdlib ``difflib``, at most
    three), or "" when none is close: the hint every "unknown name" message carries."""
    import difflib  # only a mistake needs it: loading a good scenario never pays for it

    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=3, cutoff=0.6)
    if not close:
        return ""
    return " (did you mean " + " or ".join(repr(c) for c in close) + "?)"


def first_line(error, located=True) -> str:
    """One line of an error; for a YAML syntax error its problem, where it is (line, column;
    unless not `located`: a ``--set`` value is parsed inside a wrapper) and its context."""
    problem, mark = getattr(error, "problem", None), getattr(error, "problem_mark", None)
    if problem and mark is not None:
        context = getattr(error, "context", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if located else ""
        return f"{problem}{where}" + (f" ({context})" if context else "")
    return " ".join(str(error).split("\n")[:2]).strip()
