"""Configuration of this stage (placeholder section, filled in by the stage's issue)."""

from terra.config import Section


class BuildConfig(Section):
    pass
