"""Pure models of the vehicle and its world (numpy and scipy only; no pydrake, no kernels):

- ``rotations``: quaternions (wxyz), ZYX Euler angles, yaw wrapping;
- ``dynamics``: motors, mixer, rigid body in NED/FRD, room limits;
- ``sensor_models``: noise-free measurements and how noise is applied;
- ``trajectories``: reference trajectories (files, a point, the figure eight);
- ``wind``: mean wind, gusts and Dryden turbulence;
- ``faults``: what a configured sensor fault does to one sample;
- ``fidelity``: the physical default or the reference binary's numerics;
- ``random_streams``: counter-based noise, one Philox stream per (run seed, noise name);
- ``accuracy_bound``: the best accuracy the sensors allow (hover Riccati bound, posterior CRB).
"""
