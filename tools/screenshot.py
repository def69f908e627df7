"""`python tools/screenshot.py RECORDING.rrd OUT.png [--frame N]`: render a recording headless
(clipclique.viz.screenshot; see its docstring)."""

from clipclique.viz.screenshot import main

if __name__ == "__main__":
    main()
