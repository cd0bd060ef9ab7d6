"""The text embedder: unit vectors whose bits do not depend on what the process embedded before
(a map's bytes must not depend on test order or on an earlier query)."""

import numpy as np

from terra.perception.text import normalize_rows


def test_vectors_depend_only_on_the_set_of_texts(text_embedder):
    names = ["car", "picnic table", "trash can", "a parking lot next to the tall office building", "grass"]
    # Embed subsets of different lengths first, as earlier map builds or queries would.
    text_embedder.embed_text(["car"])
    text_embedder.embed_text(["grass", "trash can", "car"])
    got = text_embedder.embed_text(names + ["car"])
    # Reference: the model itself on the sorted distinct texts, in one call.
    order = sorted(set(names))
    reference = normalize_rows(text_embedder._model.encode(order, batch_size=64, normalize_embeddings=True, convert_to_numpy=True))
    expected = reference[[order.index(n) for n in names + ["car"]]]
    assert got.dtype == np.float32 and got.shape == (6, text_embedder.dim)
    assert got.tobytes() == expected.tobytes()
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-6)
    assert text_embedder.embed_text([]).shape == (0, text_embedder.dim)
