"""Fast port and state access for the 500 Hz / 1 kHz handlers, adapted to how pydrake is bound.

drake <= 1.5x builds its Python bindings with pybind11, newer ones (e.g. 1.58) with nanobind,
and the cheapest way to read a vector input differs: measured inside a Simulator handler,
``port.Eval(context).tolist()`` costs ~2.0 us on pybind11 and ~2.7 us on nanobind, where
``port.EvalBasicVector(context).get_value().tolist()`` costs ~2.4 us and ~1.9 us.
Most of that is the numpy view of the value (~1.2 us on nanobind), so a handler that needs
one or a few entries reads them one by one (``BasicVector.GetAtIndex``, ~0.15 us each), and
a scalar of discrete state is read and written the same way (``scalar``, ``set_scalar``).
"""

from collections.abc import Callable

from pydrake.systems.framework import DiscreteStateIndex, InputPort

NANOBIND = type(InputPort.Eval).__module__.startswith("nanobind")
"""True when pydrake is bound with nanobind (drake 1.58 here)."""

STATE_PORT_COPY_LIMIT = 1000
"""Doubles up to which a state output port is Drake's own (``DeclareStateOutputPort``); a larger
one is a vector port whose calc copies the state with numpy. Drake 1.58's state port copies at
about 3.3 ns per double (24 us for 6,500, a 500-vehicle state), the numpy calc at about 0.3 ns plus
4 us of Python (6 us), measured on the 2-core machine; equal near 1,000."""


def declare_block_output(system, name, index, n, size, block) -> None:
    """Declare the output port `name` (n * block * block doubles) of `system`'s discrete-state
    group `index` holding n row-major size x size matrices: the leading block x block of each."""
    index = DiscreteStateIndex(int(index))

    def calc(context, output):
        matrices = context.get_discrete_state(index).value().reshape(n, size, size)
        output.get_mutable_value()[:] = matrices[:, :block, :block].ravel()

    system.DeclareVectorOutputPort(
        name, n * block * block, calc, prerequisites_of_calc={system.discrete_state_ticket(index)}
    )


def declare_state_output(system, name, index, size) -> None:
    """Declare the output port `name` (size doubles) of `system`'s discrete-state group `index`
    (a DiscreteStateIndex or its int)."""
    index = DiscreteStateIndex(int(index))
    if size <= STATE_PORT_COPY_LIMIT:
        system.DeclareStateOutputPort(name, index)
        return

    def calc(context, output):
        output.get_mutable_value()[:] = context.get_discrete_state(index).value()

    system.DeclareVectorOutputPort(
        name, size, calc, prerequisites_of_calc={system.discrete_state_ticket(index)}
    )


def discrete_group(system, initial, output=None) -> int:
    """Declare a discrete-state group of `system` (``initial``: its size or its values) and, when
    `output` names one, the state output port of it; the group's int index (plain ints are faster
    than DiscreteStateIndex in the 1 kHz handlers)."""
    index = system.DeclareDiscreteState(initial)
    if output is not None:
        declare_state_output(system, output, index, initial if isinstance(initial, int) else len(initial))
    return int(index)


def vector_reader(port) -> Callable[[object], list[float]]:
    """``read(context) -> list of floats``: the current value of the vector input `port`."""
    if NANOBIND:
        evaluate = port.EvalBasicVector
        return lambda context: evaluate(context).get_value().tolist()
    evaluate = port.Eval
    return lambda context: evaluate(context).tolist()


def row_reader(port, n=1) -> Callable:
    """``read(context) -> (n, size) array``: a read-only view of the vector input `port`'s value
    (no copy; valid inside the handler that reads it), the n vehicles' rows of size = port.size() / n
    (vehicle-major) for the compiled kernels."""
    evaluate = port.EvalBasicVector
    if n == 1:
        return lambda context: evaluate(context).get_value()[None]  # [None] costs 0.1 us, reshape 0.26
    size = port.size() // n
    return lambda context: evaluate(context).get_value().reshape(n, size)


def entry_reader(port, index) -> Callable[[object], float]:
    """``read(context) -> float``: entry `index` of the vector input `port`."""
    evaluate = port.EvalBasicVector
    return lambda context: evaluate(context).GetAtIndex(index)


def entries_reader(port, start, stop) -> Callable[[object], list[float]]:
    """``read(context) -> list of floats``: entries [start, stop) of the vector input `port`
    (for a few entries: each costs ~0.15 us, the whole value as a list ~2 us)."""
    evaluate = port.EvalBasicVector
    indices = range(start, stop)

    def read(context):
        return list(map(evaluate(context).GetAtIndex, indices))

    return read


def scalar(discrete_state, group) -> float:
    """Entry 0 of a discrete-state group (a DiscreteValues), as a float."""
    return discrete_state.get_vector(group).GetAtIndex(0)


def set_scalar(discrete_state, group, value) -> None:
    """Set entry 0 of a discrete-state group (a DiscreteValues) to the float `value`."""
    discrete_state.get_mutable_vector(group).SetAtIndex(0, value)
