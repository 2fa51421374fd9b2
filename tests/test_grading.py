"""Grading a student's estimator (issue 42): the course helpers against the package's scalar
maths, the template's functions and the solution's, bad input as one line, and the grader on the
correct solution and three classic mistakes."""

import importlib.util
import inspect
import math
from pathlib import Path

import numpy as np
import pytest

from quad_drake.cli import main
from quad_drake.grading import course_math, grader
from quad_drake.grading.course import FUNCTIONS, CourseFilter, StudentProblem, load_student_module
from quad_drake.grading.criteria import CRITERIA, ISOLATES
from quad_drake.models import rotations
from quad_drake.running.simulation import log_samples

HERE = Path(__file__).resolve().parent
TEMPLATE = HERE.parent / "quad_drake" / "grading" / "student_template.py"
CORRECT = HERE / "grading" / "correct_estimator.py"


def _module(path):
    spec = importlib.util.spec_from_file_location(f"grading_test_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


MISTAKES = _module(HERE / "grading" / "mistakes.py")


@pytest.fixture(scope="module")
def angles():
    rng = np.random.default_rng(42)
    return rng.uniform(-1.2, 1.2, (20, 3)) * np.array([1.0, 1.0, 2.5])


def test_batched_helpers_equal_the_scalar_rotations(angles):
    roll, pitch, yaw = angles.T
    q = course_math.quaternion_from_euler(roll, pitch, yaw)
    R = course_math.rotation_matrix(roll, pitch, yaw)
    back = np.stack(course_math.euler_from_quaternion(q), axis=-1)
    gyro = np.random.default_rng(1).normal(0.0, 2.0, (20, 3))
    turned = course_math.integrate_body_rate(q, gyro, 0.002)
    rbg_prime = _module(CORRECT).get_rbg_prime(roll, pitch, yaw)
    for i, (r, p, y) in enumerate(angles):
        np.testing.assert_allclose(q[i], rotations.quat_from_euler(r, p, y), atol=1e-12)
        np.testing.assert_allclose(R[i], rotations.rotation_from_euler(r, p, y), atol=1e-12)
        np.testing.assert_allclose(back[i], angles[i], atol=1e-12)
        np.testing.assert_allclose(
            turned[i], rotations.quat_integrate_body_rate(q[i], gyro[i], 0.002), atol=1e-12
        )
        np.testing.assert_allclose(rbg_prime[i], rotations.rotation_yaw_derivative(r, p, y), atol=1e-12)


def test_the_generic_update_is_the_textbook_kalman_update():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(7, 7))
    P = A @ A.T + np.eye(7)
    x, H, R = rng.normal(size=7), rng.normal(size=(2, 7)), np.diag([0.3, 0.5])
    z = rng.normal(size=2)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    state, cov = course_math.update(x[None], P[None], z[None], H, R, (H @ x)[None])
    np.testing.assert_allclose(state[0], x + K @ (z - H @ x), atol=1e-12)
    np.testing.assert_allclose(cov[0], (np.eye(7) - K @ H) @ P, atol=1e-12)


def test_template_and_solution_have_the_courses_six_functions_with_one_signature():
    template, solution = _module(TEMPLATE), _module(CORRECT)
    for name in FUNCTIONS:
        assert inspect.signature(getattr(template, name)) == inspect.signature(getattr(solution, name)), name
        assert "STUDENT CODE" in inspect.getsource(getattr(template, name)), name
    assert template.MEASURED_STD_DEV_GPS_POS_XY == 2.0  # the course's placeholders, not the answers
    assert template.MEASURED_STD_DEV_ACCEL_XY == 0.1
    assert set(ISOLATES) == set(CRITERIA) == set(grader.COURSE_SCENARIOS)


def test_every_mistake_patches_the_solution_once(tmp_path):
    names = [m.name for m in MISTAKES.MISTAKES]
    assert len(names) == len(set(names)) >= 10
    for mistake in MISTAKES.MISTAKES:
        assert MISTAKES.patched(mistake, tmp_path).read_text() != CORRECT.read_text()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, "no such file"),
        ("def update_from_imu(:\n", "bad.py:1: SyntaxError"),
        ("import numpy\n", "bad.py: no function update_from_imu, predict_state"),
        ("raise RuntimeError('at import')\n", "bad.py:1 in <module>: cannot import: RuntimeError: at import"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, text, message):
    path = tmp_path / "bad.py"
    if text is not None:
        path.write_text(text)
    assert main(["grade", str(path), "--runs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err


def test_a_students_exception_in_flight_names_their_frame(tmp_path):
    source = CORRECT.read_text().replace(
        "    predicted = np.array(cur_state, dtype=float)\n",
        "    predicted = np.array(cur_state, dtype=float)\n    predicted[..., 9] = 0.0\n",
    )
    path = tmp_path / "broken.py"
    path.write_text(source)
    line = source.splitlines().index("    predicted[..., 9] = 0.0") + 1
    with pytest.raises(StudentProblem) as error:
        CourseFilter(path, np.zeros((2, 7))).tick(np.tile([0.0, 0.0, 9.81], (2, 1)), np.zeros((2, 3)))
    assert str(error.value).startswith(f"broken.py:{line} in predict_state: IndexError")


def test_a_wrong_shape_names_the_function(tmp_path):
    path = tmp_path / "shape.py"
    path.write_text(CORRECT.read_text().replace("    return predicted\n", "    return predicted[..., 0:6]\n"))
    with pytest.raises(StudentProblem, match=r"predict\(\) returned shape \(3, 6\), expected \(3, 7\)"):
        CourseFilter(path, np.zeros((3, 7))).tick(np.tile([0.0, 0.0, 9.81], (3, 1)), np.zeros((3, 3)))


def test_the_template_writes_once(tmp_path, capsys):
    assert main(["grade", "--template", str(tmp_path)]) == 0
    written = tmp_path / "my_estimator.py"
    assert written.read_text() == TEMPLATE.read_text()
    load_student_module(str(written))  # imports and has the six functions
    assert main(["grade", "--template", str(tmp_path)]) == 2
    assert "exists" in capsys.readouterr().err


def test_reference_fidelity_logs_the_binarys_sample_counts():
    # SPEC §0.2's table; the golden traces hold 201, 400, 601, 2000 and 8003 rows.
    class Scenario:
        fidelity = "reference"

    counts = {}
    for end_time in (1, 2, 3, 4, 10, 20, 25, 40):
        Scenario.end_time = float(end_time)
        counts[end_time] = log_samples(Scenario)
    assert counts == {1: 201, 2: 400, 3: 601, 4: 801, 10: 2000, 20: 4000, 25: 5001, 40: 8003}
    Scenario.fidelity, Scenario.end_time = "physical", 25.0
    assert log_samples(Scenario) == 5000


RUNS = 4  # seeds per scenario: each verdict below held at 200 seeds (README "Grading")


@pytest.fixture(scope="module")
def correct_grade():
    return grader.grade(CORRECT, runs=RUNS, first_seed=3000)


@pytest.mark.slow
def test_the_correct_solution_passes_every_scenario(correct_grade):
    for scenario in correct_grade.scenarios:
        assert scenario.passes == RUNS, grader.scenario_lines(scenario)
    assert grader.grade_lines(correct_grade)[-1] == "GRADE: PASS (every scenario)"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["gps_sigma_as_variance", "small_angle_gyro", "mag_yaw_not_wrapped"])
def test_a_mistake_fails_its_scenario_and_points_at_its_function(tmp_path, name):
    mistake = next(m for m in MISTAKES.MISTAKES if m.name == name)
    result = grader.grade(MISTAKES.patched(mistake, tmp_path), RUNS, 3000, scenarios=(mistake.scenario,))
    (scenario,) = result.scenarios
    assert scenario.passes == 0
    lines = grader.scenario_lines(scenario)
    assert lines[0].startswith(f"FAIL {mistake.scenario}: 0/{RUNS}")
    assert lines[-1] == f"    -> look at {ISOLATES[mistake.scenario]}"
    assert not math.isnan(scenario.interval()[1])


def test_the_starting_file_flies_and_changes_nothing_it_should_not():
    # As the course's skeleton: it runs; the state prediction and the updates are left to the student.
    start = np.tile([0.0, 0.0, -1.0, 0.1, 0.0, 0.0, 0.2], (3, 1))
    course_filter = CourseFilter(TEMPLATE, start)
    accel, gyro = np.tile([0.0, 0.0, 9.81], (3, 1)), np.tile([0.0, 0.0, 0.5], (3, 1))
    course_filter.tick(accel, gyro, np.full(1, 0.3), np.array([1]), np.zeros((1, 6)), np.array([2]))
    np.testing.assert_allclose(course_filter.ekf_state[:, 0:6], start[:, 0:6])
    np.testing.assert_allclose(course_filter.ekf_state[:, 6], 0.2 + 0.002 * 0.5)


def test_each_context_flies_its_own_course_filter():
    # The filter's state is the context's (discrete state), not the system's.
    from conftest import assert_each_context_flies_its_own

    from quad_drake.estimation.registry import CourseEstimatorConfig
    from quad_drake.systems.course_estimator import CourseEstimator

    system = CourseEstimator(
        CourseEstimatorConfig(module=str(CORRECT)), [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.3], n=2
    )
    assert_each_context_flies_its_own(system)
