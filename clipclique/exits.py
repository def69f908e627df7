"""How every tool ends on a user mistake or an interrupt, so that all of them read alike.

A ClipcliqueError is the user's to fix: one line `TOOL: error: WHAT` on stderr and exit status 2,
no traceback. Ctrl-C: `TOOL: interrupted` and status 130. Anything else is a bug and keeps its
traceback. The console scripts, tools/demo.py and the benchmark all end through `user_errors`, and
the console scripts print their version through `version_option`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from clipclique.errors import ClipcliqueError, one_line

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports it


@contextmanager
def user_errors(tool: str) -> Iterator[None]:
    """Run the block; a ClipcliqueError or an interrupt ends the program as described above."""
    try:
        yield
    except ClipcliqueError as error:
        print(f"{tool}: error: {one_line(error)}", file=sys.stderr)
        raise SystemExit(EXIT_USER_ERROR) from None
    except KeyboardInterrupt:
        print(f"{tool}: interrupted", file=sys.stderr)
        raise SystemExit(EXIT_INTERRUPTED) from None


def version_option(tool: str) -> Callable[[bool], None]:
    """The `--version` callback of a console script: print `TOOL VERSION` and exit 0."""
    def print_version(asked: bool) -> None:
        if asked:
            from importlib.metadata import version

            print(f"{tool} {version('clipclique')}")
            raise SystemExit(0)

    return print_version
