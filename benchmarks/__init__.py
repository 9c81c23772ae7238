"""Benchmarks of the citylod pipeline (``python -m benchmarks.bench``, ``make bench``)."""
