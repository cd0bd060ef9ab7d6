"""Terra: hierarchical terrain-aware 3D scene graphs for task-agnostic outdoor mapping."""

__version__ = "0.1.0"
