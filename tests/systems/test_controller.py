"""CascadeController LeafSystem: ports, default output, tick timing, integral state."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake.config.schema import ControllerParams
from quad_drake.conventions import CONTROLLER_OFFSET, ONBOARD_PERIOD
from quad_drake.systems.controller import CascadeController

HOVER_REFERENCE = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


def level_state(z):
    return [0.0, 0.0, z, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


def make(state, params=None):
    dut = CascadeController(params or ControllerParams())
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state").FixValue(context, state)
    dut.GetInputPort("reference").FixValue(context, HOVER_REFERENCE)
    return dut, context


def test_ports_and_no_feedthrough():
    dut = CascadeController(ControllerParams())
    assert dut.get_input_port(0).get_name() == "state"
    assert dut.get_input_port(0).size() == 13
    assert dut.get_input_port(1).get_name() == "reference"
    assert dut.get_input_port(1).size() == 10
    assert dut.get_output_port(0).get_name() == "motor_thrusts"
    assert dut.get_output_port(0).size() == 4
    assert not dut.HasAnyDirectFeedthrough()


def test_default_output_is_hover_before_first_tick():
    params = ControllerParams(mass=0.4)
    dut, context = make(level_state(-0.9), params)
    np.testing.assert_allclose(dut.GetOutputPort("motor_thrusts").Eval(context), [0.981] * 4, atol=1e-12)
    simulator = Simulator(dut, context)
    simulator.AdvanceTo(CONTROLLER_OFFSET - 1e-7)
    np.testing.assert_allclose(dut.GetOutputPort("motor_thrusts").Eval(context), [0.981] * 4, atol=1e-12)


def integral_of(dut, context):
    return context.get_discrete_state(dut.integral_index()).GetAtIndex(0)


def expected_thrust_per_motor(n):
    """Level quad 0.1 m below the reference (z = -0.9) after n ticks, by hand.

    e = -0.1 per tick, integral = n (-0.1)(0.002); vz_cmd = 2 (-0.1) = -0.2;
    a_z = 8 (-0.2) + 50 integral - 9.81; T = -0.5 a_z; no moments, 4 equal forces.
    """
    integral = n * -0.1 * 0.002
    return -0.5 * (8 * -0.2 + 50 * integral - 9.81) / 4, integral


@pytest.mark.parametrize("n", [1, 5, 12])
def test_integral_and_output_after_n_ticks(n):
    dut, context = make(level_state(-0.9))
    simulator = Simulator(dut, context)
    # the n-th update fires at t = (n - 1) period + offset; stop just past it
    simulator.AdvanceTo((n - 1) * ONBOARD_PERIOD + CONTROLLER_OFFSET + 1e-7)
    per_motor, integral = expected_thrust_per_motor(n)
    assert integral_of(dut, context) == pytest.approx(integral, abs=1e-15)
    np.testing.assert_allclose(dut.GetOutputPort("motor_thrusts").Eval(context), [per_motor] * 4, atol=1e-12)
    # nothing more happens until the next tick
    simulator.AdvanceTo(n * ONBOARD_PERIOD + CONTROLLER_OFFSET - 1e-7)
    assert integral_of(dut, context) == pytest.approx(integral, abs=1e-15)


def test_five_ticks_hand_number():
    # n = 5: integral -0.001; a_z = -1.6 - 0.05 - 9.81 = -11.46; T = 5.73 N, 1.4325 N per motor
    dut, context = make(level_state(-0.9))
    Simulator(dut, context).AdvanceTo(4 * ONBOARD_PERIOD + CONTROLLER_OFFSET + 1e-7)
    np.testing.assert_allclose(dut.GetOutputPort("motor_thrusts").Eval(context), [1.4325] * 4, atol=1e-12)


def test_params_are_copied_at_construction():
    params = ControllerParams()
    dut, context = make(level_state(-1.0), params)
    params.mass = 5.0
    Simulator(dut, context).AdvanceTo(CONTROLLER_OFFSET + 1e-7)
    np.testing.assert_allclose(dut.GetOutputPort("motor_thrusts").Eval(context), [1.22625] * 4, atol=1e-12)
