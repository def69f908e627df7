"""`python tools/scene_stats.py ...`: how much a scene looks like real data (benchmark.scene_stats); see its docstring for the options."""

from benchmark.scene_stats import main

if __name__ == "__main__":
    raise SystemExit(main())
