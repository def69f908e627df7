"""User-facing errors: the CLIs print these as one clear line and exit non-zero, no traceback."""


class ClipcliqueError(Exception):
    """A mistake in the user's input (file, dataset, option), with a message that says what and where."""


class DatasetError(ClipcliqueError):
    """A dataset folder or file is missing or malformed."""


class MapFileError(ClipcliqueError):
    """A map file is missing, corrupted, or of an unsupported version."""


class ModelUnavailableError(ClipcliqueError):
    """Model weights (CLIP, YOLO) or their packages are not available here."""


def one_line(error: BaseException) -> str:
    """The error's message on one line (a library's message may span several)."""
    return " ".join(str(error).split())
