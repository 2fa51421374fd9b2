import math

import numpy as np
import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.config.schema import TRAJECTORY_DIR, TrajectoryConfig
from quad_drake.conventions import REF_A_SLICE, REF_P_SLICE, REF_V_SLICE, REF_YAW_INDEX, REFERENCE_SIZE
from quad_drake.models.rotations import wrap_to_pi
from quad_drake.models.trajectories import (
    FigureEight,
    Trajectory,
    constant_trajectory,
    figure_eight,
    load_trajectory_file,
    trajectory_from_config,
)


def packaged(name):
    return load_trajectory_file(TRAJECTORY_DIR / name)


# ----- parsing of the packaged files -------------------------------------------


@pytest.mark.parametrize(
    "name, rows",
    [("AttitudeTest.txt", 14), ("Square.txt", 19), ("FigureEight.txt", 601), ("FigureEightFF.txt", 601)],
)
def test_packaged_file_row_counts(name, rows):
    traj = packaged(name)
    assert len(traj) == rows
    assert traj.positions.shape == (rows, 3)
    assert traj.velocities.shape == (rows, 3)
    assert traj.yaws.shape == (rows,)


def test_attitude_test_columns():
    traj = packaged("AttitudeTest.txt")
    np.testing.assert_allclose(traj.times, [0, 0.1, 0.2, 0.9, 1, 1.1, 1.8, 1.9, 2, 2.7, 3, 3.2, 3.6, 3.9])
    np.testing.assert_allclose(traj.positions[1], [1, 0, -1])
    np.testing.assert_allclose(traj.positions[4], [0, -1, -1])
    np.testing.assert_allclose(traj.positions[7], [-0.7, -0.7, -1])
    np.testing.assert_allclose(traj.yaws[9:], [0, 1.57, 3.14, -1.57, 0])
    assert not traj.velocities.any() and not traj.pitches.any() and not traj.body_rates.any()


def test_square_columns():
    traj = packaged("Square.txt")
    assert traj.times[0] == 2.0 and traj.times[-1] == 20.0
    np.testing.assert_allclose(traj.positions[-1], [3, -3, -1])
    assert traj.yaws[-1] == 1.57
    np.testing.assert_allclose(traj.positions[3], [3, 3, -1])  # t = 5


def test_figure_eight_file_columns():
    plain, ff = packaged("FigureEight.txt"), packaged("FigureEightFF.txt")
    np.testing.assert_allclose(plain.times, np.arange(601) * 0.02, atol=1e-12)
    assert not plain.velocities.any() and not plain.yaws.any()
    np.testing.assert_allclose(ff.velocities[1], [2.356, 1.884, 1.178])
    np.testing.assert_array_equal(ff.positions, plain.positions)


# ----- lookup -----------------------------------------------------------------


def test_sample_layout_and_zero_feedforward():
    ref = packaged("Square.txt").sample(2.5)  # leg (0,0) -> (3,0) over [2, 3]
    assert ref.shape == (REFERENCE_SIZE,)
    np.testing.assert_allclose(ref[REF_P_SLICE], [1.5, 0, -1], atol=1e-12)
    np.testing.assert_array_equal(ref[REF_A_SLICE], 0.0)


def test_interpolation_midpoints():
    att = packaged("AttitudeTest.txt")
    np.testing.assert_allclose(att.sample(0.05)[REF_P_SLICE], [0.5, 0, -1], atol=1e-12)
    np.testing.assert_allclose(att.sample(1.85)[REF_P_SLICE], [-0.35, -0.35, -1], atol=1e-12)
    np.testing.assert_allclose(att.sample(1.075)[REF_P_SLICE], [0, -0.25, -1], atol=1e-12)
    ff = packaged("FigureEightFF.txt")
    np.testing.assert_allclose(
        ff.sample(0.03)[REF_V_SLICE], (ff.velocities[1] + ff.velocities[2]) / 2, atol=1e-12
    )
    np.testing.assert_allclose(
        ff.sample(0.025)[REF_P_SLICE], 0.75 * ff.positions[1] + 0.25 * ff.positions[2], atol=1e-12
    )


def test_knot_times_return_the_knot():
    # i = largest index with t_i < t, so t = t_k interpolates segment k-1 to its end.
    sq = packaged("Square.txt")
    np.testing.assert_allclose(sq.sample(3.0)[REF_P_SLICE], [3, 0, -1], atol=1e-12)
    assert sq.sample(4.0)[REF_YAW_INDEX] == pytest.approx(1.57, abs=1e-12)


def test_hold_after_the_end():
    sq = packaged("Square.txt")
    for t in (20.0, 20.001, 25.0, 1e4):
        ref = sq.sample(t)
        np.testing.assert_allclose(ref[REF_P_SLICE], [3, -3, -1])
        assert ref[REF_YAW_INDEX] == pytest.approx(1.57, abs=1e-12)


def test_before_first_point_returns_point_zero():
    sq = packaged("Square.txt")  # starts at t = 2
    for t in (-1.0, 0.0, 1.0, 2.0):
        np.testing.assert_array_equal(sq.sample(t), [0, 0, -1, 0, 0, 0, 0, 0, 0, 0])
    single = Trajectory([1.0], [[1.0, 2.0, 3.0]], yaws=[0.5])
    for t in (0.0, 1.0, 2.0):
        np.testing.assert_allclose(single.sample(t), [1, 2, 3, 0, 0, 0, 0, 0, 0, 0.5])


def test_yaw_interpolation_uniform_when_no_sign_flip():
    att = packaged("AttitudeTest.txt")
    # 0 -> 1.57 over [2.7, 3.0] and 1.57 -> 3.14 over [3.0, 3.2]: SLERP of yaw quaternions is uniform.
    assert att.sample(2.775)[REF_YAW_INDEX] == pytest.approx(0.3925, abs=1e-9)
    assert att.sample(3.15)[REF_YAW_INDEX] == pytest.approx(2.7475, abs=1e-9)
    assert att.sample(3.825)[REF_YAW_INDEX] == pytest.approx(-0.3925, abs=1e-9)


@pytest.mark.parametrize(
    ("name", "t0", "t1", "yaw0", "yaw1"),
    [
        ("AttitudeTest.txt", 3.2, 3.6, 3.14, -1.57),
        ("Square.txt", 7.0, 8.0, 3.14, -1.57),
        ("Square.txt", 15.0, 16.0, 3.14, -1.57),
    ],
)
def test_yaw_crossing_pi_turns_at_a_uniform_rate(name, t0, t1, yaw0, yaw1):
    # SPEC §6: the angle of the SLERP comes from the sign-aligned pair, so a pure-yaw leg
    # through +-pi turns the short way (+1.5732 rad) at a constant rate.
    traj = packaged(name)
    span = wrap_to_pi(yaw1 - yaw0)
    assert span == pytest.approx(2 * math.pi - 4.71, abs=1e-12)
    for alpha in np.linspace(0.0, 1.0, 21)[1:-1]:
        yaw = traj.sample(t0 + alpha * (t1 - t0))[REF_YAW_INDEX]
        assert wrap_to_pi(yaw - (yaw0 + alpha * span)) == pytest.approx(0.0, abs=1e-9)


def test_small_yaw_steps_use_the_lerp_branch():
    traj = Trajectory([0.0, 1.0], np.zeros((2, 3)), yaws=[0.0, 0.05])
    assert traj.sample(0.5)[REF_YAW_INDEX] == pytest.approx(0.025, abs=1e-12)
    assert traj.sample(0.25)[REF_YAW_INDEX] == pytest.approx(0.0125, abs=1e-6)


def test_yaw_of_full_attitude_slerp():
    # Same yaw, roll changes: the SLERP stays at that yaw.
    traj = Trajectory([0.0, 1.0], np.zeros((2, 3)), yaws=[0.3, 0.3], rolls=[0.0, 0.4], pitches=[0.1, 0.1])
    for t in (0.2, 0.5, 0.8):
        assert traj.sample(t)[REF_YAW_INDEX] == pytest.approx(0.3, abs=1e-6)


def test_held_yaw_is_wrapped_like_the_quaternion_yaw():
    traj = Trajectory([0.0], np.zeros((1, 3)), yaws=[4.0])
    assert traj.sample(1.0)[REF_YAW_INDEX] == pytest.approx(4.0 - 2 * math.pi, abs=1e-12)


def test_trajectory_rejects_bad_arrays():
    with pytest.raises(ValueError, match="strictly increasing"):
        Trajectory([0.0, 0.0], np.zeros((2, 3)))
    with pytest.raises(ValueError, match="shape"):
        Trajectory([0.0, 1.0], np.zeros((3, 3)))


# ----- constant and analytic -----------------------------------------------------


def test_constant_trajectory():
    traj = constant_trajectory([1.0, 2.0, -3.0], yaw=0.5)
    for t in (0.0, 7.0):
        np.testing.assert_array_equal(traj.sample(t), [1, 2, -3, 0, 0, 0, 0, 0, 0, 0.5])
    out = traj.sample(0.0)
    out[0] = 99.0
    assert traj.sample(0.0)[0] == 1.0  # callers cannot corrupt it


def test_figure_eight_formula():
    traj = figure_eight()
    t = 0.7
    w4, w2 = 2 * math.pi / 4, 2 * math.pi / 2
    expected = [
        1.5 * math.sin(w4 * t),
        0.6 * math.sin(w2 * t),
        -2 + 0.75 * math.sin(w4 * t),
        1.5 * w4 * math.cos(w4 * t),
        0.6 * w2 * math.cos(w2 * t),
        0.75 * w4 * math.cos(w4 * t),
        -1.5 * w4**2 * math.sin(w4 * t),
        -0.6 * w2**2 * math.sin(w2 * t),
        -0.75 * w4**2 * math.sin(w4 * t),
        0.0,
    ]
    np.testing.assert_allclose(traj.sample(t), expected, atol=1e-12)


def test_figure_eight_derivatives_by_central_differences():
    traj, h = FigureEight(), 1e-5
    for t in (0.0, 1.3, 5.55):
        d = (traj.sample(t + h) - traj.sample(t - h)) / (2 * h)
        np.testing.assert_allclose(d[0:3], traj.sample(t)[REF_V_SLICE], atol=1e-7)
        np.testing.assert_allclose(d[3:6], traj.sample(t)[REF_A_SLICE], atol=1e-6)


def test_packaged_figure_eight_files_match_the_formula_to_3_decimals():
    analytic = figure_eight()
    plain, ff = packaged("FigureEight.txt"), packaged("FigureEightFF.txt")
    exact = np.array([analytic.sample(t)[REF_P_SLICE] for t in plain.times])
    assert np.max(np.abs(plain.positions - exact)) <= 0.0005 + 1e-9
    assert np.max(np.abs(ff.positions - exact)) <= 0.0005 + 1e-9
    backward = np.vstack([np.zeros(3), np.diff(exact, axis=0) / 0.02])
    assert np.max(np.abs(ff.velocities - backward)) <= 0.0005 + 1e-9
    # and the file lookup reproduces the analytic positions between the points
    t = np.arange(0.005, 12.0, 0.037)
    err = [np.abs(plain.sample(s)[REF_P_SLICE] - analytic.sample(s)[REF_P_SLICE]).max() for s in t]
    assert max(err) < 0.01


# ----- from config, offsets -------------------------------------------------------


def test_offsets_from_config():
    base = packaged("Square.txt")
    cfg = TrajectoryConfig(kind="file", file="Square.txt", position_offset=[1.0, -2.0, 0.5], time_offset=0.5)
    traj = trajectory_from_config(cfg)
    for t in (0.0, 2.9, 3.25, 6.4, 30.0):
        expected = base.sample(t + 0.5)
        expected[REF_P_SLICE] += [1.0, -2.0, 0.5]
        np.testing.assert_allclose(traj.sample(t), expected, atol=1e-12)


def test_point_and_figure_eight_from_config():
    point = trajectory_from_config(
        TrajectoryConfig(kind="point", point=[1.0, 0.0, -2.0], yaw=0.3, position_offset=[0.0, 1.0, 0.0])
    )
    np.testing.assert_allclose(point.sample(4.0), [1, 1, -2, 0, 0, 0, 0, 0, 0, 0.3])
    eight = trajectory_from_config(
        TrajectoryConfig(kind="figure_eight", position_offset=[0.0, 0.0, 1.0], time_offset=1.0)
    )
    expected = figure_eight().sample(1.5)
    expected[2] += 1.0
    np.testing.assert_allclose(eight.sample(0.5), expected, atol=1e-12)


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match=r"vehicles\.0\.trajectory\.file: no such trajectory file"):
        trajectory_from_config(TrajectoryConfig(kind="file", file="Nope.txt"), "vehicles.0.trajectory")
    with pytest.raises(ConfigError, match=r"trajectory\.kind: unknown"):
        trajectory_from_config(TrajectoryConfig(kind="helix"))


# ----- malformed files --------------------------------------------------------------


@pytest.mark.parametrize(
    "text, line, message",
    [
        ("0, 0, 0, -1\n1, 0, abc, -1\n", 2, "'abc' is not a number"),
        ("# header\n\n0, 0, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 9\n", 3, "14 columns, at most 13"),
        ("0, 0, 0, -1\n1, 0, 0\n", 2, "3 column(s), at least 4 needed"),
        ("0, 0, 0, -1\n2, 0, 0, -1\n1, 0, 0, -1\n", 3, "time 1 s is not after the previous point's 2 s"),
        ("0, 0, 0, -1\n0, 1, 0, -1\n", 2, "time 0 s is not after"),
        ("0, 0, 0, -1\n1, 0, 0, -1,\n", 2, "'' is not a number"),
        ("0, 0, 0, nan\n", 1, "'nan' is not a finite number"),
    ],
)
def test_malformed_file_errors_name_file_and_line(tmp_path, text, line, message):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_trajectory_file(path)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"{path}:{line}: ")
    assert message in text


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n   \n\t# another\n"])
def test_empty_file_is_an_error(tmp_path, text):
    path = tmp_path / "empty.txt"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"empty\.txt: no trajectory points") as info:
        load_trajectory_file(path)
    assert "\n" not in str(info.value)


def test_missing_file_is_an_error(tmp_path):
    with pytest.raises(ConfigError, match=r"nothere\.txt: no such trajectory file"):
        load_trajectory_file(tmp_path / "nothere.txt")


def test_parsing_tolerates_whitespace_crlf_and_fills_trailing_columns(tmp_path):
    path = tmp_path / "ok.txt"
    path.write_bytes(
        b"  # comment\r\n0,\t1 , 2,\t-3\r\n\r\n  1.5 ,1,2,-3, 0.1, 0.2, 0.3, 0.4, 0, 0, 1, 2, 3\r\n"
    )
    traj = load_trajectory_file(path)
    np.testing.assert_array_equal(traj.times, [0.0, 1.5])
    np.testing.assert_array_equal(traj.velocities, [[0, 0, 0], [0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(traj.yaws, [0.0, 0.4])
    np.testing.assert_array_equal(traj.body_rates, [[0, 0, 0], [1, 2, 3]])
