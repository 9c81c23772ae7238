"""citylod core: what the stages (etl), the exporter and server, and the command lines share.

settings (every tunable), db and cluster (the database), pipeline (the stage graph) and stage (the stage
contract), workers (units of work as Dask tasks), changes (what an update's runs changed), reuse (keep or make
again), fingerprint, progress (stage summaries and balances), geodesy (WGS84, ECEF and east-north-up frames),
camera (the perspective camera and the screen-space-error rule), semantics (surface codes), wkb (meshes as
PolyhedralSurface WKB) and tiles3d (a tileset.json's content URIs). It imports nothing else of citylod;
tests/unit/test_layers.py keeps the import graph pointing one way: core <- exporter <- etl <- benchmarks.
"""
