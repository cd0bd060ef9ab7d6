"""Session fixtures of the mapping stage (see tests/conftest.py)."""
