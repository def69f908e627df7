"""`python tools/bench.py ...`: the benchmark suite (benchmark.suite), the command `make bench` and `make docs` run; see its docstring for the options."""

from benchmark.suite import main

if __name__ == "__main__":
    main()
