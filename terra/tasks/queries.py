"""Query text in, unit vectors out, in the embedding space the map was built with.

A map records its embedder's name and dimension; queries embedded by any other model would give
meaningless cosines, so a mismatch is refused (DESIGN.md decision 12).
"""

from __future__ import annotations

import re

import numpy as np

from terra.errors import TerraError
from terra.perception.text import TextEmbedder, normalize_rows


def clean_queries(queries: list[str] | tuple[str, ...] | str) -> list[str]:
    """Stripped query strings; TerraError for none at all or an empty one."""
    if isinstance(queries, str):
        queries = [queries]
    out = [str(q).strip() for q in queries]
    if not out:
        raise TerraError('no query given; pass at least one text query, e.g. "find the dumpster"')
    for i, q in enumerate(out):
        if not q:
            raise TerraError(f'query {i + 1} is empty; give a text query, e.g. "find the dumpster"')
        try:
            q.encode("utf-8")
        except UnicodeEncodeError as exc:  # a lone surrogate ('\ud800') from JSON or a mangled shell
            raise TerraError(
                f"query {i + 1} is not valid text: character {exc.start + 1} is a lone UTF-16 surrogate"
            ) from None
    return out


def embed_queries(embedder: TextEmbedder, queries: list[str]) -> np.ndarray:
    """(Q, D) float32 unit vectors for cleaned queries, one embedding batch."""
    return np.asarray(embedder.embed_text(clean_queries(queries)), dtype=np.float32)


QUERY_MODES = ("sentence", "phrases", "sentence+phrases")
# Connectives that join the parts of a place description ("park with a pond, a dirt trail and
# picnic tables on the grass"); longest first so "surrounded by" is not cut at "by".
_CONNECTIVES = re.compile(
    r",|;| surrounded by | lined by | between | behind | with | and | on | by ", flags=re.IGNORECASE
)


def query_phrases(query: str) -> list[str]:
    """The parts of a description split at commas and connectives (with, and, on, by, between,
    behind, surrounded by, lined by), stripped, empty parts dropped; [query] when none splits it."""
    parts = [p.strip() for p in _CONNECTIVES.split(f" {query.strip()} ")]
    return [p for p in parts if p] or [query.strip()]


def embed_query(embedder: TextEmbedder, query: str, mode: str = "sentence") -> np.ndarray:
    """(D,) float32 unit vector of one cleaned query. "sentence": the embedding of the whole text
    (the paper's); "phrases": the normalised mean of the unit embeddings of its parts
    (query_phrases), which reads a description the way a place's image embedding is built, as a
    mixture of what is there; "sentence+phrases": the mean over the whole text and its parts."""
    if mode not in QUERY_MODES:
        raise TerraError(f"unknown query mode {mode!r}; expected one of: {', '.join(QUERY_MODES)}")
    (query,) = clean_queries([query])
    if mode == "sentence":
        return embed_queries(embedder, [query])[0]  # exactly the paper's vector
    parts = query_phrases(query)
    texts = parts if mode == "phrases" or parts == [query] else [query] + parts
    unit = normalize_rows(np.asarray(embedder.embed_text(texts), dtype=np.float32))
    return normalize_rows(unit.mean(axis=0, keepdims=True))[0].astype(np.float32)
