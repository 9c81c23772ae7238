"""Helpers the tests share (servers, traversal, OSM history, comparisons); benchmarks use them too."""
