"""Fast input reads for the 500 Hz / 1 kHz handlers, adapted to how pydrake is bound.

drake <= 1.5x builds its Python bindings with pybind11, newer ones (e.g. 1.58) with nanobind,
and the cheapest way to read a vector input differs: measured inside a Simulator handler,
``port.Eval(context).tolist()`` costs ~2.0 us on pybind11 and ~2.7 us on nanobind, where
``port.EvalBasicVector(context).get_value().tolist()`` costs ~2.4 us and ~1.9 us.
"""

from pydrake.systems.framework import InputPort

NANOBIND = type(InputPort.Eval).__module__.startswith("nanobind")
"""True when pydrake is bound with nanobind (drake 1.58 here)."""


def vector_reader(port):
    """``read(context) -> list of floats``: the current value of the vector input `port`."""
    if NANOBIND:
        evaluate = port.EvalBasicVector
        return lambda context: evaluate(context).get_value().tolist()
    evaluate = port.Eval
    return lambda context: evaluate(context).tolist()
