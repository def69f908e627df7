"""Reading user files at the edges: every problem becomes a ClipcliqueError naming the file.

The readers of datasets, configs, maps and results go through these helpers so that a file
that is a folder, not UTF-8, nested too deep, too large or an image too big to decode is one
clear line for the user, never a traceback or an allocation of gigabytes. Limits are far
above anything a real scan holds (see the README, "Data").
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from clipclique.errors import ClipcliqueError

MAX_TEXT_BYTES = 256 * 2**20  # a TUM groundtruth.txt of hours holds ~100 MB
MAX_JSON_BYTES = 512 * 2**20  # a ScanNet segs.json holds ~20 MB
MAX_JSON_DEPTH = 64  # ScanNet's files nest 3 deep, ours 4
MAX_IMAGE_PIXELS = 64 * 2**20  # 8K x 8K; ScanNet colour is 1296 x 968
MAX_LABEL_CHARS = 1000  # a class name or an object description
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")  # tab and newline are fine in free text
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)


def check_file(path: Path, what: str = "file", error: type[ClipcliqueError] = ClipcliqueError) -> Path:
    """`path` when it is an existing regular file; otherwise `error` saying it is missing or a folder."""
    path = Path(path)
    if path.is_dir():
        raise error(f"{path}: is a folder, expected a {what}")
    if not path.is_file():
        raise error(f"{path}: {what} not found")
    return path


def read_bytes(path: Path, limit: int, what: str = "file", error: type[ClipcliqueError] = ClipcliqueError) -> bytes:
    """The bytes of a regular file of at most `limit` bytes."""
    check_file(path, what, error)
    try:
        size = path.stat().st_size
        if size > limit:
            raise error(f"{path}: {size / 2**20:.0f} MiB is larger than the {limit / 2**20:.0f} MiB a {what} may be")
        return path.read_bytes()
    except OSError as problem:
        raise error(f"{path}: cannot read the {what} ({problem.strerror or problem})") from None


def decode_text(data: bytes, where: str, error: type[ClipcliqueError] = ClipcliqueError) -> str:
    """Strict UTF-8 (a leading BOM dropped); NUL bytes refused, since no text format here has them."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as problem:
        line = data[: problem.start].count(b"\n") + 1
        raise error(f"{where}, line {line}: not UTF-8 text (byte "
                    f"0x{data[problem.start]:02x}); save it as UTF-8") from None
    if "\0" in text:
        line = text[: text.index("\0")].count("\n") + 1
        raise error(f"{where}, line {line}: holds a NUL byte; is this a text file?")
    return text


def check_text(value: object, where: str, error: type[ClipcliqueError] = ClipcliqueError,
               max_chars: int = MAX_LABEL_CHARS) -> str:
    """A short user string (class name, description): a str, no NUL or other control character, not too long."""
    if not isinstance(value, str):
        raise error(f"{where} must be text, got {type(value).__name__}")
    if len(value) > max_chars:
        raise error(f"{where} is {len(value)} characters long, more than the {max_chars} allowed")
    if _CONTROL.search(value):
        raise error(f"{where} {value[:40]!r} holds a control character (NUL, escape, ...)")
    return value


def read_text(path: Path, what: str = "text file", error: type[ClipcliqueError] = ClipcliqueError,
              limit: int = MAX_TEXT_BYTES) -> str:
    """A UTF-8 text file, decoded strictly."""
    return decode_text(read_bytes(path, limit, what, error), str(path), error)


def json_depth(data: bytes) -> int:
    """How deep arrays and objects nest in a JSON document (brackets inside strings ignored)."""
    outside = np.frombuffer(_JSON_STRING.sub(b'""', data), dtype=np.uint8)
    steps = ((outside == ord("[")).astype(np.int64) + (outside == ord("{")) - (outside == ord("]"))
             - (outside == ord("}")))
    return int(np.cumsum(steps).max(initial=0))


def parse_json(data: bytes | str, where: str, error: type[ClipcliqueError] = ClipcliqueError,
               max_depth: int = MAX_JSON_DEPTH) -> Any:
    """A JSON document with its nesting limited, so that a hostile one cannot exhaust the stack."""
    raw = data.encode() if isinstance(data, str) else data
    depth = json_depth(raw)
    if depth > max_depth:
        raise error(f"{where}: JSON nested {depth} levels deep, more than the {max_depth} allowed")
    try:
        return json.loads(decode_text(raw, where, error))
    except (json.JSONDecodeError, RecursionError) as problem:
        raise error(f"{where}: not valid JSON ({problem})") from None


def read_json(path: Path, what: str = "JSON file", error: type[ClipcliqueError] = ClipcliqueError,
              limit: int = MAX_JSON_BYTES) -> Any:
    """A JSON file, size- and depth-limited."""
    return parse_json(read_bytes(path, limit, what, error), str(path), error)


def read_image(path: Path, mode: str | None = None, error: type[ClipcliqueError] = ClipcliqueError,
               max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """An image as an array, its declared size checked before any pixel is decoded."""
    check_file(path, "image", error)
    return decode_image(path, str(path), mode, error, max_pixels)


def decode_image(source: Path | bytes, where: str, mode: str | None = None,
                 error: type[ClipcliqueError] = ClipcliqueError, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """An image file or encoded bytes (a bag's compressed image) as an array, its declared size checked first;
    `where` names it in the error."""
    import io

    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(source) if isinstance(source, bytes) else source) as image:
            width, height = image.size
            if width * height > max_pixels:
                raise error(f"{where}: image declares {width} x {height} pixels, more than the {max_pixels} allowed")
            # convert copies even to its own mode
            return np.asarray(image.convert(mode) if mode and image.mode != mode else image)
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as problem:
        raise error(f"{where}: unreadable image ({problem})") from None
    except ImportError:  # once ultralytics is imported, its patched Image.open tries an optional HEIF plugin on failure
        raise error(f"{where}: unreadable image (not a format Pillow reads)") from None


def read_single_channel(path: Path, what: str, error: type[ClipcliqueError] = ClipcliqueError) -> np.ndarray:
    """A single-channel integer image (depth, instance ids); a colour image is refused."""
    image = read_image(path, error=error)
    if image.ndim != 2 or image.dtype.kind not in "ui":
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise error(f"{path}: expected a single-channel integer {what} image, got {channels} "
                    f"channel(s) of {image.dtype}")
    return image
