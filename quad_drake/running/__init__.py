"""Finding, checking and flying a scenario:

- ``catalog``: the bundled scenarios and how one is loaded;
- ``limits``: what a run will cost before it starts, and the rule that refuses an absurd one;
- ``simulation``: a scenario wired into a Drake Diagram and run (one vehicle or several);
- ``progress``: the progress of one long flight on stderr;
- ``diagram_svg``: a scenario's Diagram as an SVG picture.
"""
