import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from quad_drake.config.schema import TRAJECTORY_DIR
from quad_drake.conventions import REFERENCE_SIZE
from quad_drake.models.trajectories import figure_eight, load_trajectory_file
from quad_drake.systems.trajectory import TrajectorySource


def test_output_is_the_trajectory_at_context_time():
    traj = load_trajectory_file(TRAJECTORY_DIR / "Square.txt")
    dut = TrajectorySource(traj)
    assert dut.num_input_ports() == 0
    port = dut.GetOutputPort("reference")
    assert port.size() == REFERENCE_SIZE
    context = dut.CreateDefaultContext()
    for t, p, yaw in [
        (0.0, [0, 0, -1], 0.0),
        (2.5, [1.5, 0, -1], 0.0),
        (3.5, [3, 0, -1], 0.785),
        (30.0, [3, -3, -1], 1.57),
    ]:
        context.SetTime(t)
        out = port.Eval(context)
        np.testing.assert_allclose(out[0:3], p, atol=1e-12)
        assert out[9] == pytest.approx(yaw, abs=1e-9)
        np.testing.assert_array_equal(out, traj.sample(t))


def test_logged_reference_in_a_simulation():
    builder = DiagramBuilder()
    dut = builder.AddSystem(TrajectorySource(figure_eight()))
    logger = LogVectorOutput(dut.get_output_port(), builder, publish_period=0.005)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(1.0)
    log = logger.FindLog(simulator.get_context())
    times, data = log.sample_times(), log.data()
    assert len(times) == 201
    k = 100  # t = 0.5
    assert times[k] == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_allclose(data[:, k], figure_eight().sample(0.5), atol=1e-12)
    np.testing.assert_allclose(data[0, k], 1.5 * np.sin(np.pi / 4), atol=1e-12)
