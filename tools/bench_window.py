"""`python tools/bench_window.py ...`: window localization measured (benchmark.window); see its docstring for the options."""

from benchmark.window import main

if __name__ == "__main__":
    main()
