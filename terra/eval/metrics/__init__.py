"""Evaluation metrics as pure functions over arrays: boxes, retrieval, segmentation, regions,
memory and navigation. Each module documents the definitions it implements."""
