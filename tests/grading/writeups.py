"""The five write-ups of the project (``seeds/000`` … ``004`` in the project's shared notes, not
shipped) as variants of the correct solution: their measured sigmas, their EKF tunings (the
course's value where a write-up reports none) and their attitude integration in 07 (the Euler-rate
"linear" scheme of 001, the quaternion scheme of 000, 002, 003). 004 reports neither sigmas nor a
tuning, only code (its mistake ``vz_feeds_itself`` is in ``mistakes.py``)."""

from dataclasses import dataclass, field
from pathlib import Path

from mistakes import CORRECT

COURSE_TUNING = {
    "Q_POS_XY_STD": 0.05,
    "Q_POS_Z_STD": 0.05,
    "Q_VEL_XY_STD": 0.05,
    "Q_VEL_Z_STD": 0.1,
    "Q_YAW_STD": 0.05,
    "GPS_POS_XY_STD": 1.0,
    "GPS_POS_Z_STD": 3.0,
}
"""QuadEstimatorEKF.txt as shipped (SPEC §4), for what a write-up does not report."""

LINEAR_SCHEME = (
    "    q = integrate_body_rate(quaternion_from_euler(roll_est, pitch_est, yaw_est), gyro, dt_imu)\n"
    "    predicted_roll, predicted_pitch, yaw = euler_from_quaternion(q)\n",
    "    p, q, r = gyro[..., 0], gyro[..., 1], gyro[..., 2]\n"
    "    sr, cr = np.sin(roll_est), np.cos(roll_est)\n"
    "    tp, cp = np.tan(pitch_est), np.cos(pitch_est)\n"
    "    predicted_roll = roll_est + dt_imu * (p + sr * tp * q + cr * tp * r)\n"
    "    predicted_pitch = pitch_est + dt_imu * (cr * q - sr * r)\n"
    "    yaw = yaw_est + dt_imu * (sr * q + cr * r) / cp\n"
    "    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi\n",
)
"""001's scheme: the Euler angles advanced by their rates (the body rates through the ZYX
Euler-rate matrix), one explicit step per sample."""


@dataclass(frozen=True)
class Writeup:
    label: str
    scheme: str  # "quaternion" or "linear"
    constants: dict = field(default_factory=dict)
    where: str = ""


WRITEUPS = {
    w.label: w
    for w in (
        Writeup(
            "000",
            "quaternion",
            {
                "MEASURED_STD_DEV_GPS_POS_XY": 0.72,
                "MEASURED_STD_DEV_ACCEL_XY": 0.51,
                "Q_POS_XY_STD": 0.01,
                "Q_VEL_XY_STD": 0.1,
                "Q_YAW_STD": 0.06,
            },
            "sigmas l. 68-69, QPosXYStd/QVelXYStd l. 419-420, QYawStd l. 494, "
            "FromEuler123_RPY + IntegrateBodyRate",
        ),
        Writeup(
            "001",
            "linear",
            {"MEASURED_STD_DEV_GPS_POS_XY": 0.704, "MEASURED_STD_DEV_ACCEL_XY": 0.502},
            "sigmas l. 32-33, Euler-rate integration l. 50-58; no tuning reported",
        ),
        Writeup(
            "002",
            "quaternion",
            {
                "MEASURED_STD_DEV_GPS_POS_XY": 0.709187828,
                "MEASURED_STD_DEV_ACCEL_XY": 0.487435033,
                "Q_POS_XY_STD": 0.001,
                "Q_VEL_XY_STD": 0.2,
                "Q_YAW_STD": 0.5,
            },
            "sigmas l. 30-32, QPosXYStd/QVelXYStd l. 167, QYawStd l. 173, IntegrateBodyRate_fast",
        ),
        Writeup(
            "003",
            "quaternion",
            {
                "MEASURED_STD_DEV_GPS_POS_XY": 0.6601210006202937,
                "MEASURED_STD_DEV_ACCEL_XY": 0.48476061505594636,
                "Q_POS_XY_STD": 0.1,
                "Q_VEL_XY_STD": 0.25,
                "Q_YAW_STD": 0.15,
            },
            "sigmas l. 95, QPosXYStd/QVelXYStd l. 354, QYawStd l. 396, IntegrateBodyRate",
        ),
    )
}


def written(writeup, folder):
    """The correct solution with the write-up's constants and scheme, as ``folder/writeup_<label>.py``."""
    lines = []
    values = COURSE_TUNING | writeup.constants
    for line in CORRECT.read_text().splitlines(keepends=True):
        key = line.split(" = ", 1)[0]
        lines.append(f"{key} = {values[key]!r}\n" if key in values else line)
    text = "".join(lines)
    if writeup.scheme == "linear":
        assert text.count(LINEAR_SCHEME[0]) == 1
        text = text.replace(*LINEAR_SCHEME)
    path = Path(folder) / f"writeup_{writeup.label}.py"
    path.write_text(text)
    return path
