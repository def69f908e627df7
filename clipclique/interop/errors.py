"""The one error type of the interop readers and writers."""

from clipclique.errors import ClipcliqueError


class InteropError(ClipcliqueError):
    """Another system's map, detection or trajectory file is malformed or cannot be written; the message names it."""
