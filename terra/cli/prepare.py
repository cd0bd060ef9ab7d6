"""`terra prepare`: make the text model's ONNX export now rather than on the first query."""

from __future__ import annotations

import typer

from terra.cli import app


@app.command("prepare")
def prepare_command(
    embedder: str | None = typer.Option(None, "--embedder", help="Text embedder name (default: the packaged MiniLM)."),
) -> None:
    """Export the text model to ONNX once, so queries start fast.

    Export the text embedder to ONNX into the user cache (once per machine; ~20 s), so the
    first `terra find/monitor/plan` answers in about a second. Useful in an image build or before
    a robot goes out. Prints the runtime and where the export lives ($TERRA_CACHE_DIR to move it).

    Example: terra prepare
    """
    from terra.perception.text import DEFAULT_TEXT_EMBEDDER, get_text_embedder

    model = get_text_embedder(embedder or DEFAULT_TEXT_EMBEDDER)
    model.embed_text(["warm up"])
    where = getattr(model, "folder", None)
    runtime = "onnxruntime" if where is not None else "sentence-transformers"
    typer.echo(f"{model.name}: {model.dim}-d vectors on {runtime}" + (f", export in {where}" if where else ""))
