"""Judging a flight from its logs (pure: numpy, scipy and the compiled ``kernels.jit`` only):

- ``signals``: the reference simulator's named signals and the log layout of a vehicle;
- ``error_sampling``: against which truth and reference the logged errors are taken;
- ``evaluation``: the reference's pass/fail analyzers over logged samples;
- ``safety``: the flight-safety criteria every scenario is judged on;
- ``verdicts``: a scenario's criteria checked against its signals and judged on a run;
- ``consistency``: NEES/NIS statistics of an estimator;
- ``noise_std``: the reference's step 1, the standard deviations of logged sensor noise.
"""
