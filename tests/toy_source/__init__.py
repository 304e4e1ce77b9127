"""A toy data source, a folder of its own as a new source's is (tests/test_sources_registry.py)."""
