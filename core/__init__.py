"""citylod core: what the stages (etl), the exporter and server, and the command lines share.

settings (every tunable), db and cluster (the database), progress (stage summaries), geodesy (WGS84, ECEF and
east-north-up frames), camera (the perspective camera and the screen-space-error rule), semantics (surface
codes) and wkb (meshes as PolyhedralSurface WKB). It imports nothing else of citylod; tests/unit/test_layers.py
keeps the import graph pointing one way: core <- etl <- exporter <- command lines <- benchmarks.
"""
