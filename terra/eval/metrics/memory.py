"""Memory of the saved map and graph against the mapped area (the paper's memory figure).

Bytes are the on-disk sizes of the bundle's components (`Bundle.component_bytes`). The mapped
area is the number of occupied `cell` x `cell` cells of the map points' x, y times the cell area,
as in the authors' evaluation (0.4 m cells).
"""

from __future__ import annotations

import numpy as np

from terra.bundle import Bundle


def mapped_area(points: np.ndarray, cell: float = 0.4) -> float:
    """Square metres covered by map points (N, >=2, metres): occupied xy cells times cell^2."""
    points = np.asarray(points)
    if len(points) == 0:
        return 0.0
    cells = np.floor(points[:, :2] / cell).astype(np.int64)
    return float(np.unique(cells, axis=0).shape[0] * cell * cell)


def memory_summary(bundle: Bundle, area_m2: float) -> dict:
    """Bytes per component, their total, and bytes per square metre of mapped area."""
    components = dict(sorted(bundle.component_bytes().items()))
    total = int(sum(components.values()))
    return {
        "components_bytes": components,
        "total_bytes": total,
        "area_m2": float(area_m2),
        "bytes_per_m2": total / area_m2 if area_m2 > 0 else 0.0,
    }
