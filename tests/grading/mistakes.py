"""The classic mistakes of the course's estimation project, each a small patch to the correct
solution (``correct_estimator.py``), with the function it lives in, the scenario meant to catch
it and where it comes from. ``patched(mistake, folder)`` writes the patched module.

Sources: the five write-ups of the project (``seeds/000`` … ``004`` in the project's shared
notes, not shipped), the course's own text and shipped code (SPEC §2, §4: the project README's
steps and the skeleton ``QuadEstimatorEKF.cpp``), and public write-ups found with code search
(psnx/FCND-Estimation-CPP ``writeup.md``). The course's forum is not in any searchable corpus
here, so no forum thread is cited.
"""

from dataclasses import dataclass
from pathlib import Path

CORRECT = Path(__file__).with_name("correct_estimator.py")


@dataclass(frozen=True)
class Mistake:
    name: str
    function: str  # where the student makes it
    scenario: str  # the scenario meant to isolate it
    source: str
    old: str  # text of the correct solution, replaced once
    new: str


MISTAKES = (
    Mistake(
        "gps_sigma_as_variance",
        "MEASURED_STD_DEV_GPS_POS_XY",
        "06_sensor_noise",
        "issue 42 ('a GPS sigma given as a variance'); write-up 001 computes np.std of the 06 log, "
        "np.var gives 0.49",
        "MEASURED_STD_DEV_GPS_POS_XY = 0.7",
        "MEASURED_STD_DEV_GPS_POS_XY = 0.49",
    ),
    Mistake(
        "accel_sigma_as_variance",
        "MEASURED_STD_DEV_ACCEL_XY",
        "06_sensor_noise",
        "as above for the accelerometer (write-ups 000-003 report 0.49-0.51; the variance is 0.25)",
        "MEASURED_STD_DEV_ACCEL_XY = 0.5",
        "MEASURED_STD_DEV_ACCEL_XY = 0.25",
    ),
    Mistake(
        "small_angle_gyro",
        "update_from_imu",
        "07_attitude_estimation",
        "the course's shipped UpdateFromIMU (SPEC §4: phi += dt p, theta += dt q, psi += dt r), "
        "which the README asks the student to replace; write-up 003 shows its 07 FAIL",
        "    q = integrate_body_rate(quaternion_from_euler(roll_est, pitch_est, yaw_est), gyro, dt_imu)\n"
        "    predicted_roll, predicted_pitch, yaw = euler_from_quaternion(q)\n",
        "    predicted_roll = roll_est + dt_imu * gyro[..., 0]\n"
        "    predicted_pitch = pitch_est + dt_imu * gyro[..., 1]\n"
        "    yaw = (yaw_est + dt_imu * gyro[..., 2] + np.pi) % (2 * np.pi) - np.pi\n",
    ),
    Mistake(
        "gravity_sign",
        "predict_state",
        "08_predict_state",
        "issue 42 ('the gravity sign in the state prediction'); write-ups 000-003 subtract "
        "CONST_GRAVITY, a student who adds it flies this",
        "(accel_world[..., 2] - GRAVITY)",
        "(accel_world[..., 2] + GRAVITY)",
    ),
    Mistake(
        "body_to_world_transposed",
        "predict_state",
        "08_predict_state",
        "the course's hint to rotate with Rotate_BtoI (write-ups 000 and 004 quote it); "
        "Rotate_ItoB (R transposed) is the other method of the same class",
        "rotate(rotation_matrix(roll_est, pitch_est, cur_state[..., 6]), accel)",
        "rotate(np.swapaxes(rotation_matrix(roll_est, pitch_est, cur_state[..., 6]), -1, -2), accel)",
    ),
    Mistake(
        "vz_feeds_itself",
        "predict_state",
        "08_predict_state",
        "write-up 004: predictedState(5) += (predictedState(5) - CONST_GRAVITY + global_frame.z) * dt",
        "predicted[..., 5] += (accel_world[..., 2] - GRAVITY) * dt",
        "predicted[..., 5] += (cur_state[..., 5] + accel_world[..., 2] - GRAVITY) * dt",
    ),
    Mistake(
        "rbg_prime_transposed",
        "get_rbg_prime",
        "09_predict_covariance",
        "issue 42 ('a transposed R'bg'); SPEC §4 gives its rows",
        "    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)\n\n\ndef predict(",
        "    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-1)\n\n\ndef predict(",
    ),
    Mistake(
        "process_noise_without_dt",
        "predict",
        "09_predict_covariance",
        "issue 42 ('dt missing from the process noise'); SPEC §4: Q = diag(std²) dtIMU",
        "q = np.diag(np.square(q_std)) * dt",
        "q = np.diag(np.square(q_std))",
    ),
    Mistake(
        "jacobian_transposed",
        "predict",
        "09_predict_covariance",
        "write-up 004 transposes gPrime in place between its two products (ekfCov = gPrime * ekfCov; "
        "gPrime.transposeInPlace(); ekfCov = ekfCov * gPrime + Q): one product too few or in the "
        "wrong order gives G' P G",
        "cov = g_prime @ ekf_cov @ np.swapaxes(g_prime, -1, -2) + q",
        "cov = np.swapaxes(g_prime, -1, -2) @ ekf_cov @ g_prime + q",
    ),
    Mistake(
        "mag_yaw_not_wrapped",
        "update_from_mag",
        "10_mag_update",
        "issue 42; the course README's step 4 ('make sure to correctly measure the angle error'); "
        "write-ups 001-004 all add the +-2 pi shift",
        "    z_from_x[difference > np.pi] += 2 * np.pi\n    z_from_x[difference < -np.pi] -= 2 * np.pi\n",
        "",
    ),
    Mistake(
        "mag_yaw_wrapped_one_way",
        "update_from_mag",
        "10_mag_update",
        "write-up 000 wraps the integrated yaw with one 'if' per side; dropping one side is the "
        "near miss of the same code in UpdateFromMag",
        "    z_from_x[difference < -np.pi] -= 2 * np.pi\n",
        "",
    ),
    Mistake(
        "gps_position_only",
        "update_from_gps",
        "11_gps_update",
        "the course's H for GPS is [I6 | 0] (SPEC §4); fusing the position rows alone "
        "(hPrime = [I3 0]) throws away the GPS velocity",
        "    h = np.eye(6, 7)\n    z = np.concatenate([pos, vel], axis=-1)\n"
        "    return update(ekf_state, ekf_cov, z, h, np.diag(np.square(gps_std)), ekf_state[..., 0:6])\n",
        "    h = np.eye(3, 7)\n"
        "    r = np.diag(np.square(gps_std[0:3]))\n"
        "    return update(ekf_state, ekf_cov, pos, h, r, ekf_state[..., 0:3])\n",
    ),
)


def patched(mistake, folder):
    """Write the correct solution with `mistake` applied to ``folder/<name>.py``; its path."""
    text = CORRECT.read_text()
    if text.count(mistake.old) != 1:
        raise ValueError(f"{mistake.name}: its text is not in the correct solution exactly once")
    path = Path(folder) / f"{mistake.name}.py"
    path.write_text(text.replace(mistake.old, mistake.new))
    return path
