"""`python tools/bench_core.py ...`: the algorithm's own benchmarks on simulated maps (clipclique.benchmark.core); see
its docstring for the options."""

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)

from clipclique.benchmark.core import main  # noqa: E402

if __name__ == "__main__":
    main()
