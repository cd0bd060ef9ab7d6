"""The simulator's label vocabulary: terrain, structure and object classes with render colours.

The table itself is terra.datasets.sim_classes (the SemanticKITTI writer colours its legend with
it, and dataset formats sit below the simulator).
"""

from terra.datasets.sim_classes import CLASS_COLORS, CLASS_REFLECTANCE, SIM_CLASSES, UNLABELED, class_id

__all__ = ["CLASS_COLORS", "CLASS_REFLECTANCE", "SIM_CLASSES", "UNLABELED", "class_id"]
