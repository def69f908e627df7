"""CLIP text/image encoders behind one small interface, and the real one: open_clip models.

Real CLIP (`ClipEncoder`) runs an open_clip model (the paper: ViT-L-14 with OpenAI weights) on
CUDA when present. Weights come from a local checkpoint file, the open_clip / Hugging Face
cache, or the hub when it is reachable; when it is not, `HF_HUB_OFFLINE=1` is set before
open_clip is imported so a missing file fails at once instead of after a minute of retries.

The simulated CLIP of synthetic scenes is `clipclique.sim.encoder`; `clipclique.backends.load_encoder`
picks an encoder by name.
"""

from __future__ import annotations

import os
import pickletools
import socket
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from clipclique.errors import ModelUnavailableError
from clipclique.io.safeio import parse_json

DEFAULT_MODEL = "ViT-L-14"
DEFAULT_PRETRAINED = "openai"

CHECKPOINT_SUFFIXES = (".pt", ".pth", ".bin", ".safetensors")
MAX_SAFETENSORS_HEADER = 100 * 2**20
# What torch.save writes for tensors, parameters and (ordered) dicts; nothing that runs code.
SAFE_PICKLE_GLOBALS = frozenset(
    {"collections OrderedDict", "torch._utils _rebuild_tensor_v2", "torch._utils _rebuild_parameter"}
    | {f"torch {kind}Storage" for kind in ("Float", "Double", "Half", "BFloat16", "Long", "Int", "Short", "Char",
                                           "Byte", "Bool")}
)


@dataclass(frozen=True)
class Crop:
    """A detection's image crop, and the same box of the frame's instance image where the dataset has
    one (a simulated encoder reads which objects the crop shows there; real CLIP sees pixels alone)."""

    pixels: np.ndarray  # (h, w, 3) uint8
    instances: np.ndarray | None = None  # (h, w) dataset object id per pixel, 0 = none
    truncated: bool = False  # the detection's mask touches the image border


class Encoder(Protocol):
    """What mapping (text) and localization (images) need from CLIP."""

    name: str
    simulated: bool

    def encode_text(self, texts: list[str]) -> np.ndarray:
        """(N, D) float32, L2-normalized."""
        ...

    def encode_images(self, crops: Sequence[Crop]) -> np.ndarray:
        """(K, D) float32, L2-normalized, one row per crop."""
        ...


def normalize(vectors: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (float32); zero rows stay zero."""
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return (vectors / np.maximum(norms, 1e-12)).astype(np.float32)


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
            model, _, preprocess = open_clip.create_model_and_transforms(model_name, pretrained=pretrained,
                                                                         device=device)
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
        return normalize(np.concatenate(chunks))

    def encode_images(self, crops: Sequence[Crop]) -> np.ndarray:
        import torch
        from PIL import Image

        chunks = [np.zeros((0, self.dim), np.float32)]
        with torch.inference_mode():
            for start in range(0, len(crops), self.batch_size):
                batch = torch.stack([self.preprocess(Image.fromarray(c.pixels))
                                     for c in crops[start:start + self.batch_size]])
                chunks.append(self.model.encode_image(batch.to(self.device)).float().cpu().numpy())
        return normalize(np.concatenate(chunks))


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
            raise ModelUnavailableError(f"{path}: not a torch checkpoint (not torch's zip format; "
                                        "raw pickles are refused)")
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
