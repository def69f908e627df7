"""`python tools/bench_window.py ...`: window localization measured (clipclique.benchmark.window); see its docstring for
the options."""

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)

from clipclique.benchmark.window import main  # noqa: E402

if __name__ == "__main__":
    main()
