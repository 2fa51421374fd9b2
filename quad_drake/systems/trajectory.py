"""TrajectorySource: publishes a reference trajectory (SPEC §6) as a Drake output port."""

from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import REFERENCE_SIZE
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.models.trajectories import lookup_time


class TrajectorySource(LeafSystem):
    """No inputs; output ``reference`` (n 10) = trajectory.sample(lookup_time(t)) at context time t
    (s), the same sample for each of the n vehicles (default 1), vehicle-major.

    Layout: p (3, m, NED), v (3, m/s), a feed-forward (3, m/s^2), yaw (rad). ``trajectory``
    is any object with ``sample(t) -> (10,)`` (see :mod:`quad_drake.models.trajectories`);
    ``fidelity`` (:class:`~quad_drake.models.fidelity.Fidelity`) picks the lookup clock: exact time,
    or the reference's float32 clock. The output depends on time only (cached per time
    step), so it cannot close a loop.
    """

    def __init__(self, trajectory, fidelity=PHYSICAL, n=1) -> None:
        super().__init__()
        self._trajectory, self._fidelity, self._n = trajectory, fidelity, n
        self.DeclareVectorOutputPort(
            "reference", n * REFERENCE_SIZE, self._calc_reference, prerequisites_of_calc={self.time_ticket()}
        )

    def _calc_reference(self, context, output):
        sample = self._trajectory.sample(lookup_time(context.get_time(), self._fidelity))
        if self._n == 1:  # the cheapest copy of one sample (evaluated at every step that reads it)
            output.SetFromVector(sample)
        else:  # n copies (``tests/systems/test_sized_by_n.py``: bit for bit the one-vehicle source's)
            output.get_mutable_value().reshape(self._n, REFERENCE_SIZE)[:] = sample
