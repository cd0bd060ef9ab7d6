"""Randomly initialised models built by the tests themselves (no weights exist on this machine).

- `save_clip(folder, ...)`: a CLIPModel of any size (tiny by default) with a byte-level tokenizer and a
  CLIP image processor, saved with save_pretrained, as a user's local CLIP folder would be.
- `save_seg_onnx(path, output0, protos, ...)`: an ONNX graph with the ultralytics segmentation export
  signature (input `images` (1, 3, H, W), outputs `output0` and `output1`) whose outputs are the given
  constants, so the decoded boxes and masks are known in advance; metadata as ultralytics writes it.
- `raw_output(...)`: output0 of the raw layout (1, 4 + nc + nm, anchors) from a list of detections.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _byte_vocab() -> dict[str, int]:
    from transformers.convert_slow_tokenizer import bytes_to_unicode

    chars = sorted(set(bytes_to_unicode().values()))
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for suffix in ("", "</w>"):
        for c in chars:
            vocab[c + suffix] = len(vocab)
    return vocab


def save_clip(
    folder: Path,
    seed: int = 0,
    image_size: int = 32,
    patch_size: int = 8,
    hidden: int = 32,
    layers: int = 2,
    heads: int = 4,
    projection_dim: int = 16,
    text_hidden: int | None = None,
    text_layers: int | None = None,
    text_heads: int | None = None,
) -> Path:
    """A randomly initialised CLIP model folder (weights, config, tokenizer, image processor). The defaults
    are tiny; CLIP ViT-B/16 is image_size 224, patch_size 16, hidden 768, layers 12, heads 12,
    projection_dim 512, text_hidden 512, text_heads 8."""
    import torch
    from transformers import CLIPConfig, CLIPModel, CLIPProcessor, CLIPTokenizer
    from transformers.utils import logging as hf_logging

    try:
        from transformers import CLIPImageProcessorPil as ImageProcessor
    except ImportError:  # transformers 4
        from transformers import CLIPImageProcessor as ImageProcessor

    vocab = _byte_vocab()
    text_hidden = text_hidden or hidden
    config = CLIPConfig(
        text_config=dict(
            vocab_size=len(vocab),
            hidden_size=text_hidden,
            intermediate_size=4 * text_hidden,
            num_hidden_layers=text_layers or layers,
            num_attention_heads=text_heads or heads,
            max_position_embeddings=77,
            bos_token_id=0,
            eos_token_id=1,
            pad_token_id=1,
        ),
        vision_config=dict(
            image_size=image_size,
            patch_size=patch_size,
            hidden_size=hidden,
            intermediate_size=4 * hidden,
            num_hidden_layers=layers,
            num_attention_heads=heads,
        ),
        projection_dim=projection_dim,
    )
    torch.manual_seed(seed)
    hf_logging.disable_progress_bar()
    model = CLIPModel(config).eval()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        tokenizer = CLIPTokenizer(vocab=vocab, merges=[])  # transformers 5
    except TypeError:  # transformers 4 reads its vocabulary from files
        import json

        (folder / "vocab.json").write_text(json.dumps(vocab))
        (folder / "merges.txt").write_text("#version: 0.2\n")
        tokenizer = CLIPTokenizer(str(folder / "vocab.json"), str(folder / "merges.txt"))
    processor = CLIPProcessor(
        image_processor=ImageProcessor(
            size={"shortest_edge": image_size}, crop_size={"height": image_size, "width": image_size}
        ),
        tokenizer=tokenizer,
    )
    model.save_pretrained(folder)
    processor.save_pretrained(folder)
    return folder


def raw_output(
    detections: list[tuple[tuple[float, float, float, float], int, float, np.ndarray]], nc: int, nm: int, anchors: int
) -> np.ndarray:
    """(1, 4 + nc + nm, anchors) float32: anchor i holds detection i = ((cx, cy, w, h) input pixels,
    class, score, (nm,) coefficients); the other anchors score 0."""
    out = np.zeros((1, 4 + nc + nm, anchors), dtype=np.float32)
    for i, ((cx, cy, w, h), cls, score, coeffs) in enumerate(detections):
        out[0, :4, i] = (cx, cy, w, h)
        out[0, 4 + cls, i] = score
        out[0, 4 + nc :, i] = coeffs
    return out


def save_seg_onnx(
    path: Path,
    output0: np.ndarray,
    protos: np.ndarray,
    input_hw: tuple[int, int],
    names: list[str] | None,
    half: bool = False,
    dynamic: bool = False,
    imgsz_meta: bool = True,
) -> Path:
    """An ONNX model whose outputs are the given constants (plus 0 x the input's mean, so the input is used)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    dtype = TensorProto.FLOAT16 if half else TensorProto.FLOAT
    h, w = input_hw
    dims = [1, 3, "height", "width"] if dynamic else [1, 3, h, w]
    image = helper.make_tensor_value_info("images", dtype, dims)
    shape0 = [1, output0.shape[1], "anchors"] if dynamic else list(output0.shape)
    shape1 = [1, protos.shape[1], "mask_height", "mask_width"] if dynamic else list(protos.shape)
    out0 = helper.make_tensor_value_info("output0", TensorProto.FLOAT, shape0)
    out1 = helper.make_tensor_value_info("output1", TensorProto.FLOAT, shape1)
    nodes = [
        helper.make_node("Cast", ["images"], ["images_f"], to=TensorProto.FLOAT),
        helper.make_node("ReduceMean", ["images_f"], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
        helper.make_node("Add", ["c0", "nothing"], ["output0"]),
        helper.make_node("Add", ["c1", "nothing"], ["output1"]),
    ]
    inits = [
        numpy_helper.from_array(np.asarray(output0, np.float32), "c0"),
        numpy_helper.from_array(np.asarray(protos, np.float32), "c1"),
        numpy_helper.from_array(np.zeros((), np.float32), "zero"),
    ]
    graph = helper.make_graph(nodes, "tiny-seg", [image], [out0, out1], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {"task": "segment", "stride": "32", "batch": "1"}
    if names is not None:
        meta["names"] = str({i: n for i, n in enumerate(names)})
    if imgsz_meta:
        meta["imgsz"] = str([h, w])
    for key, value in meta.items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.checker.check_model(model)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    return path
