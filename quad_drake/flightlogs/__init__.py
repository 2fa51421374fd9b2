"""Recorded flights replayed through the estimators (README "Replaying flight logs").

``reader`` turns a PX4 ULog or a CSV file into arrays of timestamped samples in the package's
units and frames; ``playback`` schedules them on the onboard tick and derives the yaw-only
magnetometer sample; ``comparison`` judges the estimate against the flight controller's own
(another estimator, not the truth), a SITL log's ground truth, and the NIS in its chi^2 band;
``earth_field`` the magnetometer as PX4 calibrated it and the world field it is fused against;
``checks`` what refuses or weakens a replay; ``replay`` wires the Diagram
(``systems.playback.LogPlayback`` feeding the estimator sub-Diagram) and runs it; ``page``
writes the run folder's report; ``recording`` writes a simulated run as a replay CSV.
"""
