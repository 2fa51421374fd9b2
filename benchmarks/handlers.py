"""Swap the event and output handlers of quad_drake's LeafSystems for the benchmarks: wrapped in
timers (``bench_closed_loop.py --breakdown``) or emptied, to measure what a Diagram's layout
costs with no maths at all (the floor no handler code can go below)."""

import contextlib
import inspect

HANDLERS = (
    "_update",
    "_sample",
    "_calc",
    "_calc_reference",
    "_book",
    "_delayed",
    "_first_step",
    "_second_step",
)
"""Names of the periodic-update and output-calc methods of the systems in quad_drake.systems and
quad_drake.campaigns.fleet (each takes (self, context, discrete_state or output))."""


@contextlib.contextmanager
def replaced_handlers(modules, replace):
    """Within the block, every HANDLERS method defined by a class of `modules` is
    ``replace(key, method)`` (key: "Class._name"); restored on exit. Build the Diagram inside
    the block: a system binds its handlers when it declares them."""
    originals = []
    try:
        for module in modules:
            for _, cls in inspect.getmembers(module, inspect.isclass):
                if cls.__module__ == module.__name__:
                    for name in HANDLERS:
                        if name in cls.__dict__:
                            originals.append((cls, name, cls.__dict__[name]))
                            setattr(cls, name, replace(f"{cls.__name__}.{name}", cls.__dict__[name]))
        yield
    finally:
        for cls, name, method in originals:
            setattr(cls, name, method)


def empty(key, method):
    """A handler that does nothing: the state and the output keep what they hold."""
    return lambda self, context, argument: None
