"""`python tools/bench.py ...`: the benchmark suite (clipclique.benchmark.suite), the command `make bench` and `make
docs` run; see its docstring for the options."""

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)

from clipclique.benchmark.suite import main  # noqa: E402

if __name__ == "__main__":
    main()
