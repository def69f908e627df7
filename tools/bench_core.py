"""`python tools/bench_core.py ...`: the algorithm's own benchmarks on simulated maps (benchmark.core); see its docstring for the options."""

from clipclique.arithmetic import pin_arithmetic

pin_arithmetic()  # before numpy loads: the same arithmetic as the CLIs (clipclique.arithmetic)

from benchmark.core import main  # noqa: E402

if __name__ == "__main__":
    main()
