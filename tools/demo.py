"""`make demo`: build the demo maps, localize both demo sequences with all four methods, compare.

The demo scenes are synthetic (generated on first use); the detector and the CLIP encoder are
the simulated stand-ins, and every table and recording says so.
"""

from __future__ import annotations

import time
from pathlib import Path

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)

from clipclique.commands import command  # noqa: E402
from clipclique.exits import user_errors  # noqa: E402
from clipclique.io.outputs import MAP_DIR  # noqa: E402
from clipclique.localization.run import RunSettings, run_and_save  # noqa: E402
from clipclique.localization.tables import make_console, print_documents  # noqa: E402
from clipclique.mapping import tables as map_tables  # noqa: E402
from clipclique.mapping.run import run_build  # noqa: E402

SEQUENCES = ("demo", "demo_tum")
METHODS = ("clipclique", "sh", "xview", "cliploc")


def main() -> None:
    """Run the demo; a ClipcliqueError (data that cannot be written, a broken map) is one line and exit 2."""
    with user_errors("demo"):
        run_demo()


def run_demo() -> None:
    console, map_console = make_console(), map_tables.make_console()
    start = time.perf_counter()
    for sequence in SEQUENCES:
        console.print(f"[bold]building the map of {sequence}[/bold]")
        map_tables.print_build(map_console, run_build(sequence))
    folders: dict[tuple[str, str], Path] = {}
    documents = []
    for sequence in SEQUENCES:
        for method in METHODS:
            console.print(f"localizing {sequence} with {method} ...")
            settings = RunSettings(sequence, method)
            documents.append(run_and_save(settings))
            folders[sequence, method] = settings.out_dir(documents[-1]["run"]["sequence"])
    console.rule("CLIP-Clique and the baselines on the demo")
    print_documents(console, documents)
    console.print(f"\nfinished in {time.perf_counter() - start:.0f} s; recordings (open with `{command('rerun')} "
                  "FILE`, several at once to compare):", highlight=False, soft_wrap=True)
    for sequence in SEQUENCES:
        console.print(f"  {'map':<12}{MAP_DIR / f'{sequence}.map.rrd'}", highlight=False, soft_wrap=True)
        for method in METHODS:
            console.print(f"  {method:<12}{folders[sequence, method] / 'recording.rrd'}", highlight=False,
                          soft_wrap=True)
    example = folders["demo_tum", "clipclique"]
    console.print("beside each recording: results.json, config.json, poses.tum and groundtruth.tum (TUM format; "
                  f"score with evo: `evo_ape tum {example / 'groundtruth.tum'} {example / 'poses.tum'}`)",
                  highlight=False, soft_wrap=True)


if __name__ == "__main__":
    main()
