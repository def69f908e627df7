"""`python tools/scene_stats.py ...`: how much a scene looks like real data (benchmark.scene_stats); see its docstring for the options."""

from clipclique.arithmetic import pin_arithmetic

pin_arithmetic()  # before numpy loads: the same arithmetic as the CLIs (clipclique.arithmetic)

from benchmark.scene_stats import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main())
