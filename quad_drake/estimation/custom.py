"""Pure: your own estimator, a plain Python class the workbench flies like its own.

Name it in a scenario::

    estimator: {kind: custom, factory: "my_ekf.py:MyEkf", params: {q_vel_std: 0.05}}

``factory`` is ``module:name`` (an importable module) or ``path/to/file.py:name`` (relative
to the scenario file, else to the working directory); ``factory(**params)`` makes one
estimator per vehicle (``params``: numbers). The object it returns has:

- ``state_names``: the entries of its state, named from :data:`STATE_NAMES` (``X Y Z`` m NED,
  ``VX VY VZ`` m/s NED, ``Roll Pitch Yaw`` rad, ZYX Euler angles of the body FRD frame);
  its covariance is over these, in this order;
- ``predict(dt, accel, gyro)``: one IMU step; dt s, accel the specific force (m/s^2, body FRD,
  about (0, 0, -9.81) at rest), gyro the body rate (rad/s, FRD);
- ``update_gps(position, velocity)``: a GPS sample, p_N (3, m) and v_N (3, m/s);
- ``update_mag(yaw)``: a magnetometer yaw, rad;
- ``estimate()``: (9,) x y z (m), vx vy vz (m/s), roll pitch yaw (rad);
- ``covariance()``: (k, k) over ``state_names``;
- optionally ``gps_innovation(position, velocity)`` -> (nu (6,), S (6, 6)) and
  ``mag_innovation(yaw)`` -> (nu (1,), S (1, 1)): the innovation the next update would use.
  With them the workbench gates the sample as it gates its own estimators (a chi^2 gate of
  ``gate_sigma`` sigma, 0 = off; a gated sample is counted and not fused) and reports its NIS;
  without them NIS is NaN and every sample is fused;
- optionally ``update_no_aid(position, velocity, std)``: a replay's no-aiding sample (PX4's fake
  position and zero velocity while not GPS-aided, ``flightlogs.schedule.no_aid_samples``), std
  (6,) the m and m/s of each component, inf where it is not fused; without it the sample goes to
  ``update_gps`` (your GPS noise).

The adapter (``systems/custom_estimator.py``) adds what the bundled estimators do around the
filter: it fuses each GPS and magnetometer sample once (by its stamp), skips and counts
non-finite samples, runs the prediction over an IMU dropout on the last finite IMU sample
and reports the body rate as NaN then (the controller then commands no moment), and fills
``diagnostics``. :func:`check_estimator` makes one estimator and runs one step of each method
on made-up samples before anything flies: a mistake is one line naming the method
(:class:`EstimatorProblem`). A method that raises during a flight is an
:class:`EstimatorRaised`: one line naming the method, the vehicle and the sim time, and the
frames of your code in its traceback (not the workbench's).

A ``path/to/file.py`` factory's folder is put on ``sys.path`` (as ``python file.py`` does), so
the file can import the modules beside it.
"""

import importlib
import importlib.util
import math
import os
import sys
import traceback
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np

from quad_drake.conventions import GRAVITY

STATE_NAMES = ("X", "Y", "Z", "VX", "VY", "VZ", "Roll", "Pitch", "Yaw")
"""The names a custom estimator's state entries may take: the columns of ``estimate()``."""
METHODS = ("predict", "update_gps", "update_mag", "estimate", "covariance")
GPS_DOF, MAG_DOF = 6, 1


class EstimatorProblem(ValueError):
    """A custom estimator that cannot fly; str() is one line. ``user_frames``: when a method of
    the estimator raised, that error's traceback from the method's frame on (your code), as
    text; else ``""``."""

    def __init__(self, message, user_frames=""):
        super().__init__(message)
        self.user_frames = user_frames


class EstimatorRaised(Exception):
    """A custom estimator failed during a flight (a method raised, or returned what cannot be
    used): ``str()`` is one line naming the vehicle, the method and the sim time;
    ``user_frames`` the traceback of your code (``""`` when nothing raised); ``copy`` which of
    the system's n estimators failed (a fleet flies copy j with its j-th seed). Picklable, so
    it crosses a process pool or a Dask cluster whole."""

    def __init__(self, line, user_frames="", copy=0):
        super().__init__(line, user_frames, copy)
        self.line, self.user_frames, self.copy = line, user_frames, copy

    def __str__(self):
        return self.line

    def with_context(self, text) -> "EstimatorRaised":
        """The same failure with `text` appended to its line (e.g. the seed and how to reproduce it)."""
        return EstimatorRaised(f"{self.line}; {text}", self.user_frames, self.copy)


def in_flight(problem, vehicle, factory, copy, time) -> EstimatorRaised:
    """The EstimatorRaised of an EstimatorProblem met at sim time `time` s by estimator `copy`
    of `vehicle` (its name), made by `factory`."""
    line = f"at t = {time:.3f} s of the flight, {vehicle}'s estimator {factory}: {problem}"
    return EstimatorRaised(line, problem.user_frames, copy)


def _one_line(error):
    text = " ".join(str(error).split()) or type(error).__name__
    return f"{type(error).__name__}: {text}"


def absolute_factory(factory, base_dir) -> str:
    """`factory` with a relative ``file.py`` path made absolute: against `base_dir` (the scenario
    file's folder) when the file is there, else the working directory; a module name unchanged."""
    location, colon, name = factory.rpartition(":")
    if not colon or not location.endswith(".py") or Path(location).is_absolute():
        return factory
    for base in (Path(base_dir), Path.cwd()):
        if (base / location).is_file():
            return f"{(base / location).resolve()}:{name}"
    return factory


def relative_factory(factory, folder) -> str:
    """`factory` with an absolute ``file.py`` path made relative to `folder` (where a scenario
    file saved there is read from: :func:`absolute_factory` makes it absolute again), so that
    the folder moves with the file beside it; unchanged when it cannot be (another drive) or
    names a module."""
    location, colon, name = factory.rpartition(":")
    if not colon or not location.endswith(".py") or not Path(location).is_absolute():
        return factory
    try:
        return f"{Path(os.path.relpath(location, Path(folder).resolve())).as_posix()}:{name}"
    except ValueError:  # Windows: another drive
        return factory


@cache
def load_factory(factory) -> Callable[..., object]:
    """The callable `factory` names (``module:name`` or ``path.py:name``); EstimatorProblem when it
    cannot be imported or is not callable."""
    location, colon, name = factory.rpartition(":")
    if not colon or not location or not name:
        raise EstimatorProblem(f"factory {factory!r}: expected 'module:name' or 'path/to/file.py:name'")
    try:
        if location.endswith(".py"):
            path = Path(location)
            if not path.is_file():
                raise EstimatorProblem(f"factory {factory!r}: no such file {location}")
            folder = str(path.resolve().parent)
            if folder not in sys.path:  # its sibling modules import, as under `python file.py`
                sys.path.insert(0, folder)
            module_name = f"quad_drake_custom_{abs(hash(str(path.resolve()))):x}"
            spec = importlib.util.spec_from_file_location(module_name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[module_name] = module  # so that its objects copy and pickle by reference
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(location)
    except EstimatorProblem:
        raise
    except Exception as e:  # the user's module failing to import, whatever its error
        raise EstimatorProblem(f"factory {factory!r}: cannot import {location}: {_one_line(e)}") from None
    made = getattr(module, name, None)
    if not callable(made):
        raise EstimatorProblem(f"factory {factory!r}: {location} has no callable {name!r}")
    return made


def make_estimator(factory, params) -> object:
    """One estimator: ``factory(**params)``; EstimatorProblem when that raises."""
    made = load_factory(factory)
    try:
        return made(**dict(params))
    except Exception as e:
        raise EstimatorProblem(f"{factory}(**params) raised {_one_line(e)}") from None


def state_names_of(estimator) -> tuple[str, ...]:
    """The estimator's ``state_names`` as a tuple, checked against :data:`STATE_NAMES`."""
    names = getattr(estimator, "state_names", None)
    if names is None:
        raise EstimatorProblem("has no state_names (its state entries, from " + " ".join(STATE_NAMES) + ")")
    names = tuple(names)
    unknown = [n for n in names if n not in STATE_NAMES]
    if not names or unknown or len(set(names)) != len(names):
        raise EstimatorProblem(
            f"state_names {names}: each must be one of {' '.join(STATE_NAMES)}, at most once"
        )
    return names


def call(estimator, method, *args) -> object:
    """``estimator.<method>(*args)``; EstimatorProblem (one line, naming the method, with the
    frames of the method's traceback as ``user_frames``) when it raises."""
    try:
        return getattr(estimator, method)(*args)
    except Exception as e:
        frames = "".join(traceback.format_exception(type(e), e, e.__traceback__.tb_next))
        raise EstimatorProblem(f"{method}() raised {_one_line(e)}", frames) from None


def _array(value, shape, what):
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        kind = type(value).__name__
        raise EstimatorProblem(f"{what} returned {kind}, expected numbers of shape {shape}") from None
    if array.shape != shape:
        raise EstimatorProblem(f"{what} returned shape {array.shape}, expected {shape}")
    return array


def read_estimate(estimator) -> np.ndarray:
    """(9,) ``estimate()`` checked for its shape."""
    return _array(call(estimator, "estimate"), (len(STATE_NAMES),), "estimate()")


def read_covariance(estimator, size) -> np.ndarray:
    """(size, size) ``covariance()`` checked for its shape."""
    return _array(call(estimator, "covariance"), (size, size), "covariance()")


def innovation(estimator, sensor, *sample) -> tuple[np.ndarray, np.ndarray] | None:
    """(nu, S) of the estimator's ``<sensor>_innovation(*sample)``, checked for its shapes, or
    None when it has no such method."""
    method = f"{sensor}_innovation"
    if not hasattr(estimator, method):
        return None
    pair = call(estimator, method, *sample)
    dof = GPS_DOF if sensor == "gps" else MAG_DOF
    if not isinstance(pair, tuple) or len(pair) != 2:
        raise EstimatorProblem(f"{method}() returned {type(pair).__name__}, expected a pair (nu, S)")
    return _array(pair[0], (dof,), f"{method}() nu"), _array(pair[1], (dof, dof), f"{method}() S")


def nis(nu, S) -> float:
    """nu^T S^-1 nu; inf when S is singular."""
    try:
        return float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        return math.inf


def check_estimator(factory, params, dt) -> tuple[str, ...]:
    """Make one estimator from `factory` and `params` and run one step of each method on made-up
    samples (a vehicle at rest at 1 m, heading north; the IMU every `dt` s); its state names.
    EstimatorProblem (one line, naming the method) at the first thing that cannot fly."""
    estimator = make_estimator(factory, params)
    missing = [m for m in METHODS if not callable(getattr(estimator, m, None))]
    if missing:
        raise EstimatorProblem(f"{factory}: the estimator has no method {', '.join(missing)}")
    names = state_names_of(estimator)
    try:
        call(estimator, "predict", dt, np.array([0.0, 0.0, -GRAVITY]), np.zeros(3))
        position, velocity = np.array([0.0, 0.0, -1.0]), np.zeros(3)
        innovation(estimator, "gps", position, velocity)
        call(estimator, "update_gps", position, velocity)
        innovation(estimator, "mag", 0.0)
        call(estimator, "update_mag", 0.0)
        estimate = read_estimate(estimator)
        covariance = read_covariance(estimator, len(names))
    except EstimatorProblem as e:
        raise EstimatorProblem(f"{factory}: {e}") from None
    if not (np.isfinite(estimate).all() and np.isfinite(covariance).all()):
        raise EstimatorProblem(f"{factory}: estimate() or covariance() is not finite after one step of each")
    return names
