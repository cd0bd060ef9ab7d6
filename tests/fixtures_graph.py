"""Session fixtures of the graph stage (see tests/conftest.py)."""
