"""The benchmark: the paper's experiments on the demo scenes and real sequences, and its report.

`suite` runs them (`python tools/bench.py`, `make bench`), `report` writes report.md and the plots,
`core` times the algorithm on simulated maps, `literal_reference` is an independent networkx
reading of the paper to compare against, `calibration` measures the confidence model held out,
`paper_tables` holds the paper's own figures, `scene_stats` measures how real a scene looks.
Runners and library only: it imports clipclique, localization and mapping, never a CLI module.
"""
