"""Pure: a student's estimator module (the course's six functions) run as one filter for n
vehicles at once.

The module (``quad-drake grade --template DIR`` writes the starting file) defines
:data:`FUNCTIONS` and the constants of :data:`TUNING_DEFAULTS` (the course's
``QuadEstimatorEKF.txt`` and 06's measured sigmas; a missing one takes the course's value).
:class:`CourseFilter` calls each function once per 500 Hz tick over the n vehicles' rows, in the
reference's order (SPEC §2, §4): ``update_from_imu`` then ``predict`` (which calls
``predict_state`` and ``get_rbg_prime``), then ``update_from_mag`` on the rows with a fresh
magnetometer sample and ``update_from_gps`` on those with a fresh GPS sample.

Any problem is a :class:`StudentProblem` whose str() is one line: a file that cannot be read or
imported, a missing function, an exception inside a function (with the student's own frame:
``my_estimator.py:42 in predict_state: ValueError: ...``) or a result of the wrong shape.
"""

import importlib.util
import sys
import traceback
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import ModuleType

import numpy as np

FUNCTIONS = (
    "update_from_imu",
    "predict_state",
    "get_rbg_prime",
    "predict",
    "update_from_mag",
    "update_from_gps",
)
"""The course's six functions (``UpdateFromIMU``, ``PredictState``, ``GetRbgPrime``, ``Predict``,
``UpdateFromMag``, ``UpdateFromGPS``), Python style."""

TUNING_DEFAULTS = {
    "MEASURED_STD_DEV_GPS_POS_XY": 2.0,  # m, 06's placeholder
    "MEASURED_STD_DEV_ACCEL_XY": 0.1,  # m/s^2, 06's placeholder
    "DT_IMU": 0.002,  # s
    "ATTITUDE_TAU": 100.0,  # s
    "INIT_STD_DEVS": (0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05),  # m, m/s, rad
    "Q_POS_XY_STD": 0.05,
    "Q_POS_Z_STD": 0.05,
    "Q_VEL_XY_STD": 0.05,
    "Q_VEL_Z_STD": 0.1,
    "Q_YAW_STD": 0.05,
    "GPS_POS_XY_STD": 1.0,
    "GPS_POS_Z_STD": 3.0,
    "GPS_VEL_XY_STD": 0.1,
    "GPS_VEL_Z_STD": 0.3,
    "MAG_YAW_STD": 0.1,
}
"""The student module's constants and the course's values (``QuadEstimatorEKF.txt``, SPEC §4;
06's placeholders) used when the module does not define them."""


class StudentProblem(ValueError):
    """A student module that cannot be graded; str() is one line."""


def _one_line(error):
    text = " ".join(str(error).split())
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def _student_frame(error, path):
    """'file.py:line in function' of the innermost frame of `error` in the student's file `path`,
    or None when none is."""
    frames = [f for f in traceback.extract_tb(error.__traceback__) if Path(f.filename) == Path(path)]
    if not frames:
        return None
    frame = frames[-1]
    return f"{Path(path).name}:{frame.lineno} in {frame.name}"


@cache
def load_student_module(path) -> ModuleType:
    """The student's module at `path` (a .py file), imported once per process; StudentProblem
    (one line) when it is missing, does not import, or lacks one of :data:`FUNCTIONS`."""
    path = Path(path)
    if not path.is_file():
        raise StudentProblem(f"{path}: no such file")
    name = f"quad_drake_student_{abs(hash(str(path.resolve()))):x}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None:
        raise StudentProblem(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SyntaxError as e:
        raise StudentProblem(f"{path.name}:{e.lineno}: SyntaxError: {e.msg}") from None
    except Exception as e:  # whatever the student's module raises on import
        where = _student_frame(e, path) or path.name
        raise StudentProblem(f"{where}: cannot import: {_one_line(e)}") from None
    sys.modules[name] = module
    missing = [f for f in FUNCTIONS if not callable(getattr(module, f, None))]
    if missing:
        raise StudentProblem(f"{path.name}: no function {', '.join(missing)}")
    return module


@dataclass(frozen=True)
class CourseTuning:
    """The student's constants (:data:`TUNING_DEFAULTS`), as arrays where the filter needs them.

    gps_sigma, accel_sigma: 06's measured GPS x-y (m) and accelerometer x-y (m/s^2) sigmas.
    dt_imu (s), attitude_tau (s); init_std (7,); q_std (7,) process noise of x y z vx vy vz yaw
    (Q = diag(q_std²) dt); gps_std (6,) m, m/s; mag_std rad.
    """

    gps_sigma: float
    accel_sigma: float
    dt_imu: float
    attitude_tau: float
    init_std: tuple
    q_std: tuple
    gps_std: tuple
    mag_std: float


def tuning_of(module) -> CourseTuning:
    """The CourseTuning of a student module (its constants, the course's where missing);
    StudentProblem when one is not a number (or, INIT_STD_DEVS, not 7 numbers)."""
    values = {}
    for key, default in TUNING_DEFAULTS.items():
        value = getattr(module, key, default)
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise StudentProblem(f"{key} = {value!r}: expected numbers") from None
        if array.shape != np.shape(default) or not np.isfinite(array).all():
            raise StudentProblem(f"{key} = {value!r}: expected {np.size(default)} finite number(s)")
        values[key] = array
    v = values
    return CourseTuning(
        gps_sigma=float(v["MEASURED_STD_DEV_GPS_POS_XY"]),
        accel_sigma=float(v["MEASURED_STD_DEV_ACCEL_XY"]),
        dt_imu=float(v["DT_IMU"]),
        attitude_tau=float(v["ATTITUDE_TAU"]),
        init_std=tuple(v["INIT_STD_DEVS"].tolist()),
        q_std=tuple(
            float(v[k])
            for k in (
                "Q_POS_XY_STD",
                "Q_POS_XY_STD",
                "Q_POS_Z_STD",
                "Q_VEL_XY_STD",
                "Q_VEL_XY_STD",
                "Q_VEL_Z_STD",
                "Q_YAW_STD",
            )
        ),
        gps_std=tuple(
            float(v[k])
            for k in (
                "GPS_POS_XY_STD",
                "GPS_POS_XY_STD",
                "GPS_POS_Z_STD",
                "GPS_VEL_XY_STD",
                "GPS_VEL_XY_STD",
                "GPS_VEL_Z_STD",
            )
        ),
        mag_std=float(v["MAG_YAW_STD"]),
    )


class CourseFilter:
    """The student's filter for n vehicles: roll_est, pitch_est (n,) rad (the complementary
    filter), ekf_state (n, 7) x y z m, vx vy vz m/s (NED), yaw rad, ekf_cov (n, 7, 7).

    path: the student's module; initial_state (n, 7): where each estimate starts (roll and pitch
    start at 0, the covariance at diag(init_std²); init_std (7,), default the module's
    INIT_STD_DEVS).
    """

    def __init__(self, path, initial_state, init_std=None):
        self.path = str(path)
        self.tuning = tuning_of(self.module)
        self.ekf_state = np.array(initial_state, dtype=float)
        n = self.ekf_state.shape[0]
        self.roll_est, self.pitch_est = np.zeros(n), np.zeros(n)
        init_std = self.tuning.init_std if init_std is None or not len(init_std) else init_std
        self.ekf_cov = np.tile(np.diag(np.square(init_std)), (n, 1, 1))
        self._q_std, self._gps_std = np.array(self.tuning.q_std), np.array(self.tuning.gps_std)

    @property
    def module(self) -> ModuleType:
        """The student's module (imported once per process; never copied with the filter)."""
        return load_student_module(self.path)

    def _call(self, function, *args):
        try:
            return getattr(self.module, function)(*args)
        except Exception as e:  # the student's code, whatever it raises
            where = _student_frame(e, self.path) or f"{Path(self.path).name} {function}()"
            raise StudentProblem(f"{where}: {_one_line(e)}") from None

    @staticmethod
    def _checked(function, value, shapes):
        """`value` (a tuple of arrays when `shapes` has several) checked against `shapes`."""
        parts = value if len(shapes) > 1 else (value,)
        if len(shapes) > 1 and (not isinstance(value, tuple) or len(value) != len(shapes)):
            raise StudentProblem(
                f"{function}() returned {type(value).__name__}, expected {len(shapes)} values"
            )
        out = []
        for part, shape in zip(parts, shapes, strict=True):
            array = np.asarray(part, dtype=float) if part is not None else None
            if array is None or array.shape != shape:
                got = None if array is None else array.shape
                raise StudentProblem(
                    f"{function}() returned shape {got}, expected {shape} (n vehicles = {shape[0]})"
                )
            out.append(array)
        return tuple(out) if len(shapes) > 1 else out[0]

    def tick(self, accel, gyro, mag_yaw=None, mag_rows=None, gps=None, gps_rows=None) -> None:
        """One 500 Hz tick: accel (n, 3) the course's accelerometer (m/s^2, body FRD, (0, 0, +9.81)
        level at rest, SPEC §2), gyro (n, 3) rad/s; mag_yaw (k,) rad for the rows `mag_rows`
        (k,) with a fresh sample; gps (k, 6) position m and velocity m/s (NED) for `gps_rows`."""
        n, t = self.ekf_state.shape[0], self.tuning
        self.roll_est, self.pitch_est, yaw = self._checked(
            "update_from_imu",
            self._call(
                "update_from_imu",
                accel,
                gyro,
                self.roll_est,
                self.pitch_est,
                self.ekf_state[:, 6],
                t.dt_imu,
                t.attitude_tau,
            ),
            ((n,), (n,), (n,)),
        )
        self.ekf_state = self.ekf_state.copy()
        self.ekf_state[:, 6] = yaw
        self.ekf_state, self.ekf_cov = self._checked(
            "predict",
            self._call(
                "predict",
                self.ekf_state,
                self.ekf_cov,
                t.dt_imu,
                accel,
                gyro,
                self.roll_est,
                self.pitch_est,
                self._q_std,
            ),
            ((n, 7), (n, 7, 7)),
        )
        if mag_rows is not None and len(mag_rows):
            self._update_rows("update_from_mag", mag_rows, mag_yaw, t.mag_std)
        if gps_rows is not None and len(gps_rows):
            self._update_rows("update_from_gps", gps_rows, gps[:, 0:3], gps[:, 3:6], self._gps_std)

    def _update_rows(self, function, rows, *measurement):
        k = len(rows)
        everyone = k == self.ekf_state.shape[0]
        state = self.ekf_state if everyone else self.ekf_state[rows]
        cov = self.ekf_cov if everyone else self.ekf_cov[rows]
        state, cov = self._checked(
            function, self._call(function, state, cov, *measurement), ((k, 7), (k, 7, 7))
        )
        if everyone:
            self.ekf_state, self.ekf_cov = state, cov
        else:
            self.ekf_state[rows], self.ekf_cov[rows] = state, cov
