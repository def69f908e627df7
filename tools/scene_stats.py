"""`python tools/scene_stats.py ...`: how much a scene looks like real data (clipclique.benchmark.scene_stats); see its
docstring for the options."""

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)

from clipclique.benchmark.scene_stats import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main())
