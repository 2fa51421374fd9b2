"""Reference trajectories (SPEC §6): files, a constant point and an analytic figure eight.

Every trajectory has ``sample(t) -> reference`` (10,) in the `reference` layout of
:mod:`quad_drake.conventions`: p (m, NED), v (m/s), a feed-forward (m/s^2), yaw (rad).
``t`` is the simulation time in s; each trajectory adds its own ``time_offset``
before the lookup and its ``position_offset`` (m) to the position afterwards, as
the reference's ``BaseController::GetNextTrajectoryPoint`` does.

File lookup follows the reference's E-sim (``Trajectory::NextTrajectoryPoint``):
i = the largest index with t_i < t; past the last point it is held; before or at
t_0 point 0 is returned; otherwise position and velocity are interpolated linearly
and the attitude by the reference's ``Quaternion::Interpolate_SLERP``, whose yaw
is the reference yaw. Files carry no acceleration, so a = 0.

:func:`lookup_time` maps the simulation time to the time a trajectory is looked up at:
the exact time, or with ``fidelity.float32_clock`` the reference's float32 clock.
"""

import bisect
import math
from pathlib import Path

import numpy as np

from quad_drake.config.errors import ConfigError
from quad_drake.config.validation import resolve_trajectory_file
from quad_drake.conventions import PHYSICS_PERIOD, REFERENCE_SIZE
from quad_drake.models.rotations import quat_from_euler

FILE_COLUMNS = ("t", "x", "y", "z", "vx", "vy", "vz", "yaw", "pitch", "roll", "p", "q", "r")
"""Columns of a trajectory file line (s, m NED, m/s, rad, rad/s); trailing ones default to 0."""

SLERP_DOT_THRESHOLD = 0.9995
"""Above this quaternion dot product the reference SLERP falls back to a normalised LERP."""

_HOLD, _LERP, _SLERP = 0, 1, 2

_clock_table = np.zeros(1, dtype=np.float32)  # float32 clock after n physics steps, n = index


def float32_clock(steps) -> float:
    """The reference's ``simulationTime`` (s) after `steps` physics steps (SPEC §0.2).

    A float32 that starts at 0 and adds 0.001f once per step, rounding every sum to float32:
    it drifts from steps * 0.001 by -0.40 ms at 8 s and +0.41 ms at 10 s. Sequential float32
    sums are tabulated once (numpy's ``cumsum`` accumulates in order).
    """
    global _clock_table
    if steps >= _clock_table.size:
        size = max(2 * _clock_table.size, steps + 1)
        _clock_table = np.concatenate(
            ([np.float32(0.0)], np.cumsum(np.full(size - 1, np.float32(0.001)), dtype=np.float32))
        )
    return float(_clock_table[steps])


def lookup_time(t, fidelity) -> float:
    """Time (s) at which a trajectory is looked up at simulation time t (s).

    t itself, or with ``fidelity.float32_clock`` the reference's float32 clock after the
    round(t / PHYSICS_PERIOD) physics steps that precede t.
    """
    if fidelity.float32_clock:
        return float32_clock(round(t / PHYSICS_PERIOD))
    return t


def _yaw_of(w, x, y, z):
    """Yaw (rad) of a wxyz quaternion of any norm, as the reference's ``Quaternion::Yaw``."""
    return math.atan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)


def _segment_attitude(q0, q1):
    """Precomputed data of the reference SLERP from q0 to q1 (wxyz tuples).

    Reproduces ``Quaternion::Interpolate_SLERP`` of the E-sim as the reference binary
    runs it (SPEC §6, measured on ``golden/08_PredictState``): q1 is first sign-aligned
    with q0 (negated when the dot product of the vector parts is negative), and the
    angle theta comes from the full dot product of the *aligned* pair. The result is
    the short-path SLERP at a uniform rate, also on pure-yaw segments that cross +-pi
    (e.g. yaw 3.14 -> -1.57, whose alignment flips q1).
    """
    if q0 == q1:
        return (_HOLD, _yaw_of(*q0))
    sign = -1.0 if q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3] < 0.0 else 1.0
    b1 = tuple(sign * c for c in q1)
    dot = max(-1.0, min(1.0, sum(a * b for a, b in zip(q0, b1, strict=True))))
    if dot > SLERP_DOT_THRESHOLD:
        return (_LERP, q0, tuple(b - a for a, b in zip(q0, b1, strict=True)))
    theta = math.acos(dot)
    return (_SLERP, q0, b1, theta, 1.0 / math.sin(theta))


def _interpolated_yaw(att, alpha):
    """Yaw (rad) of the reference SLERP described by ``att`` at fraction alpha in [0, 1]."""
    mode = att[0]
    if mode == _HOLD:
        return att[1]
    if mode == _LERP:
        q0, dq = att[1], att[2]
        return _yaw_of(
            q0[0] + alpha * dq[0], q0[1] + alpha * dq[1], q0[2] + alpha * dq[2], q0[3] + alpha * dq[3]
        )
    q0, b1, theta, inv_sin = att[1], att[2], att[3], att[4]
    w0 = math.sin((1.0 - alpha) * theta) * inv_sin
    w1 = math.sin(alpha * theta) * inv_sin
    return _yaw_of(
        w0 * q0[0] + w1 * b1[0], w0 * q0[1] + w1 * b1[1], w0 * q0[2] + w1 * b1[2], w0 * q0[3] + w1 * b1[3]
    )


class Trajectory:
    """Way-point trajectory with the E-sim lookup (linear interpolation + reference SLERP).

    Args:
        times: (N,) strictly increasing, s.
        positions, velocities: (N, 3) m and m/s, NED; velocities default to 0.
        yaws, pitches, rolls: (N,) rad, ZYX Euler angles of each point; default 0.
        body_rates: (N, 3) rad/s, FRD; stored for completeness, not part of ``sample``.
        position_offset: (3,) m added to every sampled position.
        time_offset: s added to the lookup time.
    """

    def __init__(
        self,
        times,
        positions,
        velocities=None,
        yaws=None,
        pitches=None,
        rolls=None,
        body_rates=None,
        position_offset=(0.0, 0.0, 0.0),
        time_offset=0.0,
    ):
        self.times = np.array(times, dtype=float).reshape(-1)
        n = len(self.times)
        if n == 0:
            raise ValueError("a trajectory needs at least one point")
        if np.any(np.diff(self.times) <= 0.0):
            raise ValueError("trajectory times must be strictly increasing")

        def column(values, shape):
            out = np.zeros(shape) if values is None else np.array(values, dtype=float)
            if out.shape != shape:
                raise ValueError(f"expected shape {shape}, got {out.shape}")
            return out

        self.positions = column(positions, (n, 3))
        self.velocities = column(velocities, (n, 3))
        self.yaws = column(yaws, (n,))
        self.pitches = column(pitches, (n,))
        self.rolls = column(rolls, (n,))
        self.body_rates = column(body_rates, (n, 3))
        self.position_offset = column(position_offset, (3,))
        self.time_offset = float(time_offset)

        quats = [
            tuple(float(c) for c in quat_from_euler(r, p, y))
            for r, p, y in zip(self.rolls, self.pitches, self.yaws, strict=True)
        ]
        shifted = self.positions + self.position_offset
        self._times = self.times.tolist()
        # Per point: (p + offset, v, yaw of the point's quaternion) for holds.
        self._points = [
            (*shifted[i].tolist(), *self.velocities[i].tolist(), _yaw_of(*quats[i])) for i in range(n)
        ]
        # Per segment i -> i+1: t_i, 1/dt, p_i, dp, v_i, dv, attitude interpolation data.
        self._last = n - 1
        self._segments = []
        for i in range(n - 1):
            dp = (shifted[i + 1] - shifted[i]).tolist()
            dv = (self.velocities[i + 1] - self.velocities[i]).tolist()
            self._segments.append(
                (
                    self._times[i],
                    1.0 / (self._times[i + 1] - self._times[i]),
                    *self._points[i][:6],
                    *dp,
                    *dv,
                    _segment_attitude(quats[i], quats[i + 1]),
                )
            )

    def __len__(self):
        return len(self._times)

    def sample(self, t) -> np.ndarray:
        """Reference (10,) at simulation time t (s): p, v, a = 0, yaw."""
        t = t + self.time_offset
        i = bisect.bisect_left(self._times, t) - 1  # largest index with t_i < t
        if i < 0 or i == self._last:  # t <= t_0: point 0; past the last point: hold it
            px, py, pz, vx, vy, vz, yaw = self._points[max(i, 0)]
            return np.array((px, py, pz, vx, vy, vz, 0.0, 0.0, 0.0, yaw))
        (t0, inv_dt, px, py, pz, vx, vy, vz, dpx, dpy, dpz, dvx, dvy, dvz, att) = self._segments[i]
        a = (t - t0) * inv_dt
        return np.array(
            (
                px + a * dpx,
                py + a * dpy,
                pz + a * dpz,
                vx + a * dvx,
                vy + a * dvy,
                vz + a * dvz,
                0.0,
                0.0,
                0.0,
                _interpolated_yaw(att, a),
            )
        )


class ConstantTrajectory:
    """A fixed set-point: position (3,) m NED, yaw rad, zero velocity and acceleration."""

    def __init__(self, point, yaw=0.0, position_offset=(0.0, 0.0, 0.0)):
        self.point = np.array(point, dtype=float) + np.array(position_offset, dtype=float)
        if self.point.shape != (3,):
            raise ValueError(f"expected a 3-vector point, got shape {self.point.shape}")
        self.yaw = math.atan2(math.sin(yaw), math.cos(yaw))
        self._reference = np.zeros(REFERENCE_SIZE)
        self._reference[0:3] = self.point
        self._reference[9] = self.yaw

    def sample(self, t) -> np.ndarray:
        """Reference (10,); the same at every time t (s)."""
        return self._reference.copy()


def constant_trajectory(point, yaw=0.0, position_offset=(0.0, 0.0, 0.0)) -> ConstantTrajectory:
    """Constant set-point trajectory (SPEC §6 "non-file trajectories")."""
    return ConstantTrajectory(point, yaw, position_offset)


class FigureEight:
    """Analytic figure eight (the generator of FigureEight.txt), NED, yaw 0.

    p_k(t) = center_k + amplitude_k sin(2 pi t / period_k), with exact velocity and
    acceleration feed-forward. Defaults: x = 1.5 sin(2 pi t/4), y = 0.6 sin(2 pi t/2),
    z = -2 + 0.75 sin(2 pi t/4) (m). Defined for all t (no hold at the ends).
    """

    def __init__(
        self,
        amplitude=(1.5, 0.6, 0.75),
        period=(4.0, 2.0, 4.0),
        center=(0.0, 0.0, -2.0),
        position_offset=(0.0, 0.0, 0.0),
        time_offset=0.0,
    ):
        self.amplitude = tuple(float(a) for a in amplitude)
        self.omega = tuple(2.0 * math.pi / float(T) for T in period)
        self.center = tuple(float(c) + float(o) for c, o in zip(center, position_offset, strict=True))
        self.time_offset = float(time_offset)

    def sample(self, t) -> np.ndarray:
        """Reference (10,) at simulation time t (s)."""
        t = t + self.time_offset
        out = np.empty(REFERENCE_SIZE)
        for k in range(3):
            amp, w = self.amplitude[k], self.omega[k]
            s, c = math.sin(w * t), math.cos(w * t)
            out[k] = self.center[k] + amp * s
            out[3 + k] = amp * w * c
            out[6 + k] = -amp * w * w * s
        out[9] = 0.0
        return out


def figure_eight(position_offset=(0.0, 0.0, 0.0), time_offset=0.0) -> FigureEight:
    """The default analytic figure eight (SPEC §6 formulas)."""
    return FigureEight(position_offset=position_offset, time_offset=time_offset)


def _parse_line(text, where):
    """Floats of one data line; raises ConfigError naming ``where`` (file:line)."""
    fields = text.split(",")
    if len(fields) > len(FILE_COLUMNS):
        raise ConfigError(
            f"{where}: {len(fields)} columns, at most {len(FILE_COLUMNS)} allowed ({', '.join(FILE_COLUMNS)})"
        )
    if len(fields) < 4:
        raise ConfigError(f"{where}: {len(fields)} column(s), at least 4 needed (t, x, y, z)")
    values = []
    for name, field in zip(FILE_COLUMNS, fields, strict=False):
        field = field.strip()
        try:
            value = float(field)
        except ValueError:
            raise ConfigError(f"{where}: column {name!r}: {field!r} is not a number") from None
        if not math.isfinite(value):
            raise ConfigError(f"{where}: column {name!r}: {field!r} is not a finite number")
        values.append(value)
    return values + [0.0] * (len(FILE_COLUMNS) - len(values))


def load_trajectory_file(path, position_offset=(0.0, 0.0, 0.0), time_offset=0.0) -> Trajectory:
    """Trajectory from a reference file (SPEC §6 format).

    One point per line, ``t, x, y, z, vx, vy, vz, yaw, pitch, roll, p, q, r``
    (4 to 13 comma-separated numbers, trailing ones 0; blanks around commas allowed).
    Blank lines and lines starting with ``#`` are skipped. Any problem raises a
    one-line ConfigError naming the file and the line number.
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such trajectory file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read trajectory file ({e})") from None
    rows = []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        row = _parse_line(text, f"{path}:{number}")
        if rows and row[0] <= rows[-1][0]:
            raise ConfigError(
                f"{path}:{number}: time {row[0]:g} s is not after the previous "
                f"point's {rows[-1][0]:g} s (times must increase)"
            )
        rows.append(row)
    if not rows:
        raise ConfigError(f"{path}: no trajectory points (only blank or comment lines)")
    data = np.array(rows)
    return Trajectory(
        times=data[:, 0],
        positions=data[:, 1:4],
        velocities=data[:, 4:7],
        yaws=data[:, 7],
        pitches=data[:, 8],
        rolls=data[:, 9],
        body_rates=data[:, 10:13],
        position_offset=position_offset,
        time_offset=time_offset,
    )


def trajectory_from_config(cfg, where="trajectory") -> Trajectory | FigureEight | ConstantTrajectory:
    """Trajectory object (with ``sample(t)``) of a :class:`~quad_drake.config.TrajectoryConfig`.

    ``where`` is the config path used in error messages (e.g. ``vehicles.0.trajectory``).
    """
    offset = tuple(cfg.position_offset)
    if cfg.kind == "point":
        return ConstantTrajectory(cfg.point, cfg.yaw, position_offset=offset)
    if cfg.kind == "file":
        path = resolve_trajectory_file(cfg.file, f"{where}.file")
        return load_trajectory_file(path, position_offset=offset, time_offset=cfg.time_offset)
    if cfg.kind == "figure_eight":
        return FigureEight(position_offset=offset, time_offset=cfg.time_offset)
    raise ConfigError(f"{where}.kind: unknown trajectory kind {cfg.kind!r}")
