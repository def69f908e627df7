"""`python tools/bench_window.py ...`: window localization measured (benchmark.window); see its docstring for the options."""

from clipclique.arithmetic import pin_arithmetic

pin_arithmetic()  # before numpy loads: the same arithmetic as the CLIs (clipclique.arithmetic)

from benchmark.window import main  # noqa: E402

if __name__ == "__main__":
    main()
