"""`python tools/bench_core.py ...`: the algorithm's own benchmarks on simulated maps (benchmark.core); see its docstring for the options."""

from benchmark.core import main

if __name__ == "__main__":
    main()
