"""The library in a few names: a `Localizer` and the openers it needs, above every other module.

Each is a thin wrapper over what `clipclique-map build` and `clipclique-loc run` use, so that a script
gets the same detector, encoder and configuration the CLI would pick, without six imports:

    seq = clipclique.open_sequence("demo")
    loc = clipclique.Localizer("outputs/maps/demo.map.npz", sequence=seq)
    result = loc.localize(seq[0])
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from clipclique import backends
from clipclique.config import LocalizationConfig, make_config
from clipclique.datasets import BagOptions, Sequence
from clipclique.errors import ClipcliqueError
from clipclique.interop.detections import FileDetector
from clipclique.io import mapfile
from clipclique.localization.run import (
    check_encoder,
    choose_detector,
    choose_query_encoder,
    met_by_detections,
    observe_with,
)
from clipclique.localization.runs import RunSettings
from clipclique.mapping import build
from clipclique.outcomes import LocalizationResult
from clipclique.perception.detectors import Detector
from clipclique.perception.encoders import Encoder
from clipclique.pipeline import MapIndex, index_map, localize
from clipclique.resolve import default_detector, open_scene
from clipclique.types import Frame, Map, Observations


class Localizer:
    """One map, indexed once, and one method's configuration: `.localize(frame)` detects, observes and
    localizes a dataset frame; `.localize_observations(obs)` localizes observations made elsewhere.

    `detector` and `encoder` are `--detector`/`--encoder` names or back-ends; left None they are chosen as
    `clipclique-loc run` chooses them: the sequence's detector (`sequence` needed) and the map's encoder.
    `overrides` are `--set KEY=VALUE` strings. Run-wide facts (alpha forced to 0, ...) are in `.notes`."""

    def __init__(self, map_or_path: Map | str | Path, method: str = "clipclique",
                 detector: Detector | str | None = None, encoder: Encoder | str | None = None,
                 overrides: Iterable[str] = (), *, sequence: Sequence | None = None,
                 config_file: Path | None = None) -> None:
        self.map: Map = map_or_path if isinstance(map_or_path, Map) else mapfile.load_map(Path(map_or_path))
        map_name = "the map" if isinstance(map_or_path, Map) else str(map_or_path)
        self.config: LocalizationConfig = make_config(method, config_file, list(overrides))
        self.notes: list[str] = []
        settings = RunSettings(sequence.name if sequence is not None else map_name, method,
                               detector=detector if isinstance(detector, str) else None,
                               encoder=encoder if isinstance(encoder, str) else None)
        self.detector: Detector | None = detector if not isinstance(detector, str) else None
        if self.detector is None and (sequence is not None or isinstance(detector, str)):
            if sequence is None:
                raise ClipcliqueError(f"Localizer(detector={detector!r}): pass sequence= (its object classes)")
            self.map = met_by_detections(self.map, detector or default_detector(sequence), None, self.notes)
            self.detector = choose_detector(settings, sequence, self.map, self.notes)
        self.encoder: Encoder | None = (encoder if encoder is not None and not isinstance(encoder, str) else
                                        choose_query_encoder(settings, self.config, self.map, sequence, self.notes))
        check_encoder(self.config, self.encoder, self.map, map_name, method, self.notes)
        if isinstance(self.detector, FileDetector):
            self.notes += self.detector.meet_by_text(self.encoder)
        self.index: MapIndex = index_map(self.map, self.config)

    def localize(self, frame: Frame) -> LocalizationResult:
        """Ranked camera-to-map poses for a dataset frame: detected, its ellipsoids fitted, crops embedded."""
        if self.detector is None:
            raise ClipcliqueError("Localizer.localize: no detector; pass detector= or sequence= to the Localizer")
        seen = observe_with(self.detector, self.encoder, self.config.observations, frame)
        return self.localize_observations(seen.observations)

    def localize_observations(self, observations: Observations) -> LocalizationResult:
        """Ranked camera-to-map poses for one frame's observations (`clipclique.pipeline.localize`)."""
        return localize(observations, self.index, self.config)


def load_map(path: str | Path) -> Map:
    """A map file (`clipclique-map build`'s .map.npz), checked; a bad file is a MapFileError naming it."""
    return mapfile.load_map(Path(path))


def open_sequence(name: str | Path, data_root: Path | None = None, bag: BagOptions | None = None) -> Sequence:
    """A ScanNet scene, TUM sequence, ROS bag or generated scene by name or path, as `clipclique-loc run`
    opens it (a generated scene is generated under `<data_root>/demo/` on first use)."""
    return open_scene(str(name), None if data_root is None else Path(data_root), bag=bag)


def build_map(sequence: Sequence | str, encoder: Encoder | str | None = None, data_root: Path | None = None,
              out: Path | None = None) -> Map:
    """The map of a sequence (its annotated instances fitted as ellipsoids, descriptions embedded by `encoder`:
    default "simulated" on a generated scene, else "auto"), saved to `out` when given."""
    opened = open_sequence(sequence, data_root) if isinstance(sequence, str) else sequence
    if encoder is None or isinstance(encoder, str):
        encoder = load_encoder(encoder or ("simulated" if opened.synthetic else "auto"), opened)
    map, _ = build.build_map(opened, encoder)
    if out is not None:
        mapfile.save_map(map, Path(out))
    return map


def make_detector(kind: str, sequence: Sequence, map: Map, **options) -> Detector:
    """The detector a `--detector` name gives (`clipclique.backends.DETECTORS`) for `sequence`'s objects,
    reporting `map`'s classes; `options` are backends.make_detector's (yolo_weights, seed, min_score, ...)."""
    return backends.make_detector(kind, sequence.object_classes(), map.class_names, **options)


def load_encoder(spec: str = "auto", sequence: Sequence | None = None, device: str | None = None) -> Encoder | None:
    """The CLIP encoder an `--encoder` spec names (None for "none", and for "auto" without weights); the
    simulated one knows `sequence`'s descriptions."""
    return backends.load_encoder(spec, device, scene=sequence)
