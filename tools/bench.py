"""`python tools/bench.py ...`: the benchmark suite (benchmark.suite), the command `make bench` and `make docs` run; see its docstring for the options."""

from clipclique.arithmetic import pin_arithmetic

pin_arithmetic()  # before numpy loads: the same arithmetic as the CLIs (clipclique.arithmetic)

from benchmark.suite import main  # noqa: E402

if __name__ == "__main__":
    main()
