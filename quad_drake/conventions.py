"""Shared constants: gravity, rates, signal layouts and the within-tick order."""

import math

GRAVITY = 9.81
"""Magnitude of gravity, m/s^2. In NED, ``g_N = (0, 0, +GRAVITY)``."""

PHYSICS_PERIOD = 0.001
"""Plant integration step, s (1 kHz)."""

ONBOARD_PERIOD = 0.002
"""Tick of IMU, attitude filter, EKF and controller, s (500 Hz)."""

PX4_UPDATE_PERIOD = 0.010
"""s: PX4 EKF2's update period (``EKF2_PREDICT_US``): its delayed IMU sums the samples over it
(``eskf.manoeuvre_levels``), it fuses the gravity vector once per period (a filter updating every
dt fuses it with the variance gravity_std^2 PX4_UPDATE_PERIOD / dt, the same information per
second: ``eskf.gravity_variance``), and it tests its sensor timeouts once per period
(``gating.height_restarts``)."""

LOG_PERIOD = 0.005
"""Logger sampling period, s, as the reference's 5 ms analyzer frames."""

# Within one onboard tick at t_k every system fires at t_k + offset, so each one
# reads what the previous one wrote in the same tick: sensors -> attitude filter
# -> EKF -> controller -> plant. Every distinct event time costs a full Simulator step
# (~7-9 us of framework overhead with one vehicle), so the offsets share times where the
# order allows: 6 steps per tick instead of 8.
# - the IMU fires at t_k itself, together with the noise RandomSources (period
#   ONBOARD_PERIOD, offset 0). Drake applies their (unrestricted) redraw before any
#   discrete update of the same step, so each sample reads a fresh draw; the loggers
#   publish at the end of the step that reaches t, before the updates at t, so a
#   5 ms sample still shows the IMU output held since t_k - ONBOARD_PERIOD.
# - GPS and magnetometer fire SLOW_SENSOR_OFFSET after their own noise redraw, before
#   the EKF; their times coincide with the attitude filter's only up to rounding.
# - the plant steps twice per tick: at t_k + PLANT_OFFSET (t_k -> t_k + PHYSICS_PERIOD)
#   and at t_k + PHYSICS_PERIOD + PLANT_OFFSET, using two draws of one 500 Hz source.
# - a sensor fault system (systems/faults.py, only on vehicles with faults) fires FAULT_LAG
#   after its sensor, before the sensor's first consumer: the IMU's between the IMU and the
#   attitude filter, the GPS's and magnetometer's between them and the EKF.
TICK_EPSILON = 1e-6
SENSOR_OFFSET = 0.0
SLOW_SENSOR_OFFSET = 1 * TICK_EPSILON
ATTITUDE_FILTER_OFFSET = 1 * TICK_EPSILON
EKF_OFFSET = 2 * TICK_EPSILON
CONTROLLER_OFFSET = 3 * TICK_EPSILON
PLANT_OFFSET = 4 * TICK_EPSILON
FAULT_LAG = 0.5 * TICK_EPSILON
# the no-aiding failsafe supervisor (systems/failsafe.py, only on vehicles with a failsafe) fires
# after the estimator and before the controller, which flies the reference it chose this tick
FAILSAFE_OFFSET = 2.5 * TICK_EPSILON

# ----- signal layouts ---------------------------------------------------------
# `state` (13): p_NB (3, m), q_NB (4, wxyz), v_NB (3, m/s), w_NB_B (3, rad/s)
STATE_SIZE = 13
P_SLICE = slice(0, 3)
Q_SLICE = slice(3, 7)
V_SLICE = slice(7, 10)
W_SLICE = slice(10, 13)

# `reference` (10): p (3, m), v (3, m/s), a (3, m/s^2) feed-forward, yaw (rad)
REFERENCE_SIZE = 10
REF_P_SLICE = slice(0, 3)
REF_V_SLICE = slice(3, 6)
REF_A_SLICE = slice(6, 9)
REF_YAW_INDEX = 9

# `imu` (6): f_B specific force (3, m/s^2), w_NB_B gyro (3, rad/s)
IMU_SIZE = 6
# `gps` (7): p_NB (3, m), v_NB (3, m/s), stamp (s, time of the sample, -1 = none yet)
GPS_SIZE = 7
# `mag` (2): yaw (rad, wrapped to [-pi, pi]), stamp (s, -1 = none yet)
MAG_SIZE = 2
NO_SAMPLE_STAMP = -1.0
# `attitude` (3): roll, pitch, yaw (rad) from the complementary filter
ATTITUDE_SIZE = 3
# `ekf_state` (7): x, y, z (m), vx, vy, vz (m/s), yaw (rad); NED
EKF_STATE_SIZE = 7
# `motor_thrusts` (4, N): motors 0..3 = front-left, front-right, rear-left, rear-right
NUM_MOTORS = 4

SQRT2 = math.sqrt(2.0)

# ----- aiding sensors (issue 32) ----------------------------------------------
# `mag` of a 3-axis magnetometer (MagParams.three_axis) (4): m_B (3, gauss, body FRD), stamp (s)
MAG_FIELD_SIZE = 4
# `baro` (2): pressure height (m, up, above the datum z_N = 0), stamp (s, -1 = none yet)
BARO_SIZE = 2
# `gps_accuracy` (4): a replay's GPS receiver's own accuracy of each sample, as it reports it (PX4's
# eph, epv, s_variance_m_s): horizontal position (m), vertical position (m), speed (m/s) std, then
# the GPS sample's stamp (s, -1 = none yet)
GPS_ACCURACY_SIZE = 4
# `no_aid` (13): a replay's no-aiding sample (PX4's fake position / zero velocity while not GPS-aided):
# p_N (3, m), v_N (3, m/s), the std of each of those six (m, m/s; inf = that component not
# fused), stamp (s, -1 = none yet)
NO_AID_SIZE = 13
