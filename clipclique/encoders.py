"""CLIP text/image encoders behind one small interface: real open_clip models, or a simulated CLIP.

Real CLIP (`ClipEncoder`) runs an open_clip model (the paper: ViT-L-14 with OpenAI weights) on
CUDA when present. Weights come from a local checkpoint file, the open_clip / Hugging Face
cache, or the hub when it is reachable; when it is not, `HF_HUB_OFFLINE=1` is set before
open_clip is imported so a missing file fails at once instead of after a minute of retries.

The simulated CLIP (`SimulatedClipEncoder`, name "simulated-clip") stands in for CLIP on
synthetic data whose true object descriptions are known. Its model, in unit vectors of R^D:

- Text: every content word w has a fixed random direction h(w) (seeded by a hash of the word);
  a description's text embedding is normalize(g + normalize(sum_w h(w))), where g is one
  direction shared by all texts. So descriptions sharing words are similar ("a black office
  chair" . "a purple office chair" ~ 0.83) and unrelated ones still sit near 0.5, as CLIP's
  text embeddings of object phrases do.
- Image: a crop shows its object and whatever else falls in its box (`CropTruth`: each
  labelled thing's description and share of the box's pixels; background and structure count
  as the shared direction g). Its embedding is normalize(q * c + n), c = normalize(sum of
  share * text(description)), n a random unit vector seeded by (crop bytes, contents, seed);
  an object filling its box has cosine about q / sqrt(1 + q^2) with its own text, and every
  neighbour in the box pulls the embedding towards that neighbour's text, as the context of
  a crop does to real CLIP. The signal q = q_max * size * visible:
  size = min(1, sqrt(area / 96^2)) weakens small crops, visible = 0.6 for an object cut by the
  image border. With q_max = 0.45 the correct similarity is at best ~0.41 and its margin over a
  wrong description shrinks with shared words: CLIP as the paper reports it, weakly
  discriminative (best similarities near 0.4 where Semantic Histograms reach 0.8).
  A false detection's box holds no object of its own, only what lies behind it.

Everything is deterministic: the same crop, contents and seed give the same embedding.
"""

from __future__ import annotations

import hashlib
import os
import pickletools
import re
import socket
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from clipclique.errors import ClipcliqueError, ModelUnavailableError
from clipclique.safeio import parse_json

DEFAULT_MODEL = "ViT-L-14"
DEFAULT_PRETRAINED = "openai"
SIMULATED_NAME = "simulated-clip"

CHECKPOINT_SUFFIXES = (".pt", ".pth", ".bin", ".safetensors")
MAX_SAFETENSORS_HEADER = 100 * 2**20
# What torch.save writes for tensors, parameters and (ordered) dicts; nothing that runs code.
SAFE_PICKLE_GLOBALS = frozenset(
    {"collections OrderedDict", "torch._utils _rebuild_tensor_v2", "torch._utils _rebuild_parameter"}
    | {f"torch {kind}Storage" for kind in ("Float", "Double", "Half", "BFloat16", "Long", "Int", "Short", "Char", "Byte", "Bool")}
)

_STOP_WORDS = frozenset({"a", "an", "the", "of", "on", "in", "with", "and", "photo", "this", "is"})


@dataclass(frozen=True)
class CropTruth:
    """What a crop really shows, for the simulated encoder: every labelled thing inside the box.

    `contents` pairs a description (None: unlabelled background or structure) with its share
    of the crop's pixels; the detected object is one of them, its neighbours the others.
    """

    contents: tuple[tuple[str | None, float], ...]
    truncated: bool = False  # the object is cut by the image border

    @staticmethod
    def of(description: str | None) -> CropTruth:
        return CropTruth(((description, 1.0),))


Truth = CropTruth | str | None  # a plain description means the crop shows that object alone


class Encoder(Protocol):
    """What mapping (text) and localization (images) need from CLIP."""

    name: str
    simulated: bool

    def encode_text(self, texts: list[str]) -> np.ndarray:
        """(N, D) float32, L2-normalized."""
        ...

    def encode_images(self, crops: list[np.ndarray], truth: Sequence[Truth] | None = None) -> np.ndarray:
        """(K, D) float32, L2-normalized, from (h, w, 3) uint8 crops.

        `truth` (what each crop really shows) is read by the simulated encoder only; real CLIP
        sees pixels alone.
        """
        ...


def _normalize(vectors: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return (vectors / np.maximum(norms, 1e-12)).astype(np.float32)


def _seed(*parts: bytes | str) -> int:
    digest = hashlib.blake2b(digest_size=8)
    for part in parts:
        digest.update(part.encode() if isinstance(part, str) else part)
        digest.update(b"\0")
    return int.from_bytes(digest.digest(), "little")


class SimulatedClipEncoder:
    """A documented stand-in for CLIP on synthetic data (see the module docstring)."""

    simulated = True

    def __init__(self, dim: int = 512, q_max: float = 0.45, ref_side: float = 96.0,
                 truncated_visibility: float = 0.6, seed: int = 0) -> None:
        self.name = SIMULATED_NAME
        self.dim = dim
        self.q_max = q_max
        self.ref_side = ref_side
        self.truncated_visibility = truncated_visibility
        self.seed = seed
        self._shared = self._direction("<shared>")
        self._texts: dict[str, np.ndarray] = {}  # text -> embedding: a run embeds the map's few descriptions again and again

    def _direction(self, key: str) -> np.ndarray:
        rng = np.random.default_rng(_seed(str(self.seed), key))
        return _normalize(rng.standard_normal(self.dim))

    def _text(self, text: str) -> np.ndarray:
        if text not in self._texts:
            words = [w for w in re.findall(r"[a-z0-9]+", text.lower()) if w not in _STOP_WORDS]
            content = _normalize(np.sum([self._direction(w) for w in words], axis=0)) if words else 0.0
            self._texts[text] = _normalize(self._shared + content)
        return self._texts[text]

    def encode_text(self, texts: list[str]) -> np.ndarray:
        return np.stack([self._text(t) for t in texts]) if texts else np.zeros((0, self.dim), np.float32)

    def signal(self, crop_shape: tuple[int, ...], truncated: bool) -> float:
        """q of the module docstring: weaker for small and for border-cut crops."""
        size = min(1.0, float(np.sqrt(crop_shape[0] * crop_shape[1])) / self.ref_side)
        return self.q_max * size * (self.truncated_visibility if truncated else 1.0)

    def encode_images(self, crops: list[np.ndarray], truth: Sequence[Truth] | None = None) -> np.ndarray:
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        truth = truth if truth is not None else [None] * len(crops)
        if len(truth) != len(crops):
            raise ValueError(f"{len(crops)} crops but {len(truth)} truths")
        out = []
        for crop, seen in zip(crops, truth):
            seen = seen if isinstance(seen, CropTruth) else CropTruth.of(seen)
            crop = np.ascontiguousarray(crop)
            target = _normalize(sum(share * (self._shared if d is None else self._text(d)) for d, share in seen.contents))
            rng = np.random.default_rng(_seed(str(self.seed), crop.tobytes(), str(crop.shape), repr(seen.contents)))
            noise = _normalize(rng.standard_normal(self.dim))
            out.append(self.signal(crop.shape, seen.truncated) * target + noise)
        return _normalize(np.stack(out))


class ClipEncoder:
    """A real open_clip model: batched, normalized embeddings, on CUDA when available."""

    simulated = False

    def __init__(self, model, preprocess, tokenizer, name: str, device: str, batch_size: int = 32) -> None:
        self.model = model.to(device).eval()
        self.preprocess = preprocess
        self.tokenizer = tokenizer
        self.name = name
        self.device = device
        self.batch_size = batch_size
        self.dim = int(model.visual.output_dim)

    @classmethod
    def load(cls, model_name: str = DEFAULT_MODEL, pretrained: str = DEFAULT_PRETRAINED,
             device: str | None = None, batch_size: int = 32) -> ClipEncoder:
        """Build `model_name` with weights `pretrained` (an open_clip tag or a checkpoint file).

        Raises ModelUnavailableError when the packages or the weights are not here.
        """
        if Path(pretrained).is_file():
            check_checkpoint(Path(pretrained))  # before torch is even imported
        _prefer_offline_hub()
        try:
            import open_clip
            import torch
        except ImportError as error:
            raise ModelUnavailableError(
                f"real CLIP needs torch and open_clip_torch ({error}); install the 'models' extra "
                "or use --encoder simulated / none") from None
        if model_name not in open_clip.list_models():
            raise ModelUnavailableError(f"unknown open_clip model {model_name!r} (see open_clip.list_models())")
        if not Path(pretrained).is_file():
            _check_weights(open_clip, model_name, pretrained)
        device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        try:
            model, _, preprocess = open_clip.create_model_and_transforms(model_name, pretrained=pretrained, device=device)
        except Exception as error:  # open_clip and torch raise many types for weights that do not fit the model
            if not Path(pretrained).is_file():
                raise
            raise ModelUnavailableError(f"{pretrained}: not {model_name} weights ({type(error).__name__}: "
                                        f"{str(error).splitlines()[0] if str(error) else ''})") from None
        return cls(model, preprocess, open_clip.get_tokenizer(model_name), f"open_clip:{model_name}/{pretrained}",
                   device, batch_size)

    def encode_text(self, texts: list[str]) -> np.ndarray:
        import torch

        chunks = [np.zeros((0, self.dim), np.float32)]
        with torch.inference_mode():
            for start in range(0, len(texts), self.batch_size):
                tokens = self.tokenizer(texts[start:start + self.batch_size]).to(self.device)
                chunks.append(self.model.encode_text(tokens).float().cpu().numpy())
        return _normalize(np.concatenate(chunks))

    def encode_images(self, crops: list[np.ndarray], truth: Sequence[Truth] | None = None) -> np.ndarray:
        import torch
        from PIL import Image

        chunks = [np.zeros((0, self.dim), np.float32)]
        with torch.inference_mode():
            for start in range(0, len(crops), self.batch_size):
                batch = torch.stack([self.preprocess(Image.fromarray(c)) for c in crops[start:start + self.batch_size]])
                chunks.append(self.model.encode_image(batch.to(self.device)).float().cpu().numpy())
        return _normalize(np.concatenate(chunks))


def load_encoder(spec: str = "auto", device: str | None = None, batch_size: int = 32) -> Encoder | None:
    """The encoder a spec names.

    "auto": real CLIP (ViT-L-14/openai) when its weights are here or downloadable, else None;
    "simulated": the simulated CLIP (synthetic data with known descriptions only); "none": None;
    "open_clip:MODEL/PRETRAINED" (PRETRAINED a tag or a checkpoint file) or a checkpoint path
    (ViT-L-14 architecture): real CLIP, or ModelUnavailableError saying what is missing.
    """
    if spec == "none":
        return None
    if spec in ("simulated", SIMULATED_NAME):
        return SimulatedClipEncoder()
    if spec == "auto":
        try:
            return ClipEncoder.load(device=device, batch_size=batch_size)
        except ModelUnavailableError:
            return None
    if spec.startswith("open_clip:"):
        model_name, sep, pretrained = spec.removeprefix("open_clip:").partition("/")
        if not sep or not model_name or not pretrained:
            raise ClipcliqueError(f"--encoder {spec!r}: expected open_clip:MODEL/PRETRAINED, e.g. open_clip:ViT-L-14/openai")
        return ClipEncoder.load(model_name, pretrained, device, batch_size)
    if Path(spec).suffix in CHECKPOINT_SUFFIXES:
        if not Path(spec).is_file():
            raise ModelUnavailableError(f"--encoder {spec}: checkpoint file not found")
        return ClipEncoder.load(DEFAULT_MODEL, spec, device, batch_size)
    raise ClipcliqueError(
        f"--encoder {spec!r}: choose auto, simulated, none, open_clip:MODEL/PRETRAINED or a checkpoint file")


def check_checkpoint(path: Path) -> None:
    """Refuse, without unpickling anything, a file that is not a weights checkpoint.

    A `.safetensors` file must have its JSON header; any other file must be torch's zip format
    whose pickle references only tensor-rebuilding functions (read by opcode, never executed).
    A legacy raw pickle, a TorchScript archive or junk is refused: a checkpoint must not run code.
    """
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
            if path.suffix == ".safetensors":
                size = int.from_bytes(head, "little") if len(head) == 8 else -1
                if not 2 <= size <= min(MAX_SAFETENSORS_HEADER, path.stat().st_size - 8):
                    raise ModelUnavailableError(f"{path}: not a safetensors file (no valid header)")
                parse_json(handle.read(size), f"{path}: safetensors header", ModelUnavailableError)
                return
        if not zipfile.is_zipfile(path):
            raise ModelUnavailableError(f"{path}: not a torch checkpoint (not torch's zip format; raw pickles are refused)")
        with zipfile.ZipFile(path) as archive:
            pickles = [name for name in archive.namelist() if name.endswith("/data.pkl")]
            if len(pickles) != 1:
                raise ModelUnavailableError(f"{path}: not a torch checkpoint (no data.pkl in the archive)")
            references = {arg for op, arg, _ in pickletools.genops(archive.read(pickles[0])) if "GLOBAL" in op.name}
    except (OSError, zipfile.BadZipFile, ValueError, EOFError) as error:
        raise ModelUnavailableError(f"{path}: unreadable checkpoint ({type(error).__name__}: {error})") from None
    unsafe = sorted(str(r) for r in references if r not in SAFE_PICKLE_GLOBALS)
    if unsafe:
        raise ModelUnavailableError(f"{path}: the checkpoint's pickle references {', '.join(unsafe[:3])}; "
                                    "only tensors and dicts are accepted (the file is not loaded)")


def _check_weights(open_clip, model_name: str, tag: str) -> None:
    """Resolve the weights of a pretrained tag (cache, else hub) or raise ModelUnavailableError."""
    config = open_clip.get_pretrained_cfg(model_name, tag)
    if not config:
        raise ModelUnavailableError(f"open_clip has no pretrained tag {tag!r} for {model_name} "
                                    f"(tags: {', '.join(open_clip.list_pretrained_tags_by_model(model_name))})")
    try:
        open_clip.pretrained.download_pretrained(config)
    except Exception as error:  # hub / URL errors come in many types; all mean "not here"
        raise ModelUnavailableError(
            f"CLIP weights {model_name}/{tag} are not in the cache and cannot be downloaded "
            f"({type(error).__name__}); pass --encoder with a local checkpoint file "
            "(open_clip:MODEL//path/to/weights.pt) or use --encoder simulated / none") from None


def _prefer_offline_hub() -> None:
    """Set HF_HUB_OFFLINE=1 when the user left it unset and the hub is unreachable."""
    if "HF_HUB_OFFLINE" not in os.environ and not host_reachable("huggingface.co"):
        os.environ["HF_HUB_OFFLINE"] = "1"


def host_reachable(host: str, timeout_s: float = 1.0) -> bool:
    """Whether a TCP connection to host:443 opens within the timeout (a cheap online test)."""
    try:
        socket.create_connection((host, 443), timeout=timeout_s).close()
    except OSError:
        return False
    return True
