"""The scalar numpy forms of the filter steps are reference oracles: no simulation calls them.

Single runs and fleets both execute the compiled kernels (``kernels/attitude.py``, ``ekf7.py``,
``eskf.py``, ``fusion.py``; sized by n, ``systems/estimators.py``), which compile the pure scalar
formulas' own code; the textbook matrix forms in ``estimation/`` stay as the named oracles those
kernels are tested against (``tests/test_fleet_estimators.py``, 1e-12). Here every oracle is
patched to raise and closed-loop flights that exercise every filter step (prediction,
magnetometer and GPS updates, a gated outlier, a delayed GPS, both estimators) must still fly.
"""

import pytest

from quad_drake.estimation import ekf, eskf, gsf
from quad_drake.running import catalog, simulation

ORACLES = {
    gsf: ("initial_bank", "predict_bank", "fuse_velocity_bank", "gaussian_sum_yaw", "eskf_yaw_reset"),
    ekf: (
        "predict",
        "predict_with_yaw",
        "predict_state",
        "predict_jacobian",
        "predict_covariance",
        "kalman_update",
        "gps_update",
        "mag_update",
        "tilt_process_noise",
    ),
    eskf: (
        "predict",
        "predict_nominal",
        "transition",
        "process_noise",
        "joseph_update",
        "inject",
        "gps_update",
        "mag_update",
        "gravity_update",
        "gravity_fusion_active",
        "manoeuvre_levels",
    ),
}
FLIGHTS = {
    "11_gps_update": (),
    "11_gps_update_eskf": (),
    "13_gps_outlier": ("vehicles.0.faults.0.time=1.5",),  # the outlier gated within the flight
    "14_gps_delay": (),
    "26_gsf_yaw_alignment": (),  # the EKF-GSF started and fusing (its reset: tests/test_gsf.py)
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(FLIGHTS))
def test_no_simulation_calls_the_scalar_oracles(name, monkeypatch):
    called = []

    def forbid(module, function):
        def oracle(*args, **kwargs):
            called.append(f"{module.__name__}.{function}")
            raise AssertionError(f"{module.__name__}.{function} is an oracle; a simulation called it")

        monkeypatch.setattr(module, function, oracle)

    for module, functions in ORACLES.items():
        for function in functions:
            forbid(module, function)
    scenario = catalog.load(name, overrides=("end_time=3.0",) + FLIGHTS[name])
    result = simulation.run(scenario)
    assert not called
    assert result.times[-1] == pytest.approx(3.0)
    diagnostics = result.logs["Quad"]["diagnostics"]
    assert diagnostics[-1, 1] > 2.0  # GPS samples were fused up to the end (their stamps)
    if name == "13_gps_outlier":
        from quad_drake.estimation.vocabulary import DIAG

        assert diagnostics[-1, DIAG["gps_gated"]] >= 1
