#!/usr/bin/env python3
"""`tools/screenshot.py RECORDING.rrd OUT.png [--frame N]` (in the activated .venv): render a recording headless
(clipclique.viz.screenshot; see its docstring). A `--frame` the recording does not hold shows the nearest, with
a warning."""

from clipclique.viz.screenshot import main

if __name__ == "__main__":
    main()
