"""``python -m etl serve`` (= ``python -m exporter serve``): the CesiumJS viewer and one tileset, streamed either
from an exported directory (``--dir``, the default) or from the database (``--db``: the live generation an export
published into pub.*; ``--db --live``: built on request from the stage tables), by a Starlette application on
uvicorn.

Routes (GET and HEAD; OPTIONS answers CORS preflights):

* ``/`` and ``/index.html`` -> exporter/viewer/index.html
* ``/viewer/<file>``        -> exporter/viewer/
* ``/cesium/<path>``        -> node_modules/cesium/Build/Cesium/ (CesiumJS runs offline from here)
* ``/tiles/<path>``         -> the tileset: files of the tileset directory, or in DB mode ``/tiles/tileset.json``,
  ``/tiles/subtrees/...`` and ``/tiles/content/L/X/Y.glb``: the published files, or (live) built on request by the
  exporter's own functions (exporter/export.py); the same bytes the file export writes, at the same URLs, so the
  viewer works unchanged in every mode.

Modules, each one idea:

* ``run``     listening, the announced URL, uvicorn, signals; ``serve``, ``serve_published`` and ``serve_db``
* ``app``     the ASGI application: routes, CORS, the DB mode's tile endpoint (ETag/304, gzip, 400/404/503)
* ``files``   the viewer, CesiumJS and the tileset directory from disk; media types
* ``paths``   what a request path may name: strict decoding, traversal refused, tile addresses
* ``published`` the DB mode's tileset: the live generation of a published one, cached by content
* ``source``  the live DB mode's tileset: built by the exporter, cached, dropped when a pipeline run lands
* ``cache``   the LRU of answers with a byte budget and single flight
* ``payload`` one cached answer (stored once, gzip when it pays), its ETags, content negotiation
* ``reader``  the read-only role and its psycopg_pool connections; a database outage answered at once
"""
