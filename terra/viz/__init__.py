"""Figures: top-down renders of maps, places, regions, boxes and paths (matplotlib, Agg, no
pyplot state), written as PNGs without timestamps so the same input gives the same bytes."""
