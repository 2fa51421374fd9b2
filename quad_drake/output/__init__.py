"""What a run leaves behind (no Diagram is built here):

- ``outdir``: output folders, atomic writes, the lock concurrent invocations share;
- ``jsonio``: strict JSON for every file written;
- ``results``: a run's results in memory and its versioned run folder;
- ``plots``, ``report``: the reference-style PNGs and the self-contained HTML pages;
- ``export``: per-vehicle CSV logs;
- ``meshcat_animation``: a run's 3D animation in Meshcat.
"""
