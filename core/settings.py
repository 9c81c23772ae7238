"""Every tunable of the pipeline in one place.

Each field has a documented default; an environment variable ``CITYLOD_<FIELD>`` (upper case) overrides it.
``python -m etl config`` prints the effective value of each with its override. Stages record the values they used in
``meta.pipeline_run.params`` so a run can be reproduced.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Settings:
    # --- database -------------------------------------------------------------------------------------------
    #: Port of the local cluster under var/pg (ignored when DATABASE_URL is set).
    pg_port: int = 55432
    #: Database name in the local cluster.
    pg_database: str = "citylod"

    # --- ingest ---------------------------------------------------------------------------------------------
    #: pyosmium node-location index. "flex_mem" switches from a sparse to a dense array as the file grows, so
    #: it scales to country extracts; use "dense_file_array,<path>" for planet-sized input.
    location_index: str = "flex_mem"
    #: Footprints smaller than this (m², after repair) are rejected as slivers. Small on purpose: mapped
    #: building:parts such as church pinnacles are 0.3 m² (Munich).
    min_area_m2: float = 0.01
    #: Heights above this (m) are treated as tagging errors (the tallest building is 828 m).
    max_height_m: float = 1000.0
    #: Level counts above this are treated as tagging errors.
    max_levels: float = 200.0

    # --- lod ------------------------------------------------------------------------------------------------
    #: Height of one storey (m): height = (building:levels + roof:levels) × level_height when `height` is
    #: missing; min_height = building:min_level × level_height when `min_height` is missing.
    level_height_m: float = 3.0
    #: Storeys assumed when neither height nor levels are tagged (per building type below, else this).
    default_levels: float = 3.0
    #: Storeys assumed for small building types when untagged.
    default_levels_by_type: dict[str, float] = field(
        default_factory=lambda: {
            "garage": 1,
            "garages": 1,
            "carport": 1,
            "shed": 1,
            "hut": 1,
            "cabin": 1,
            "kiosk": 1,
            "toilets": 1,
            "service": 1,
            "bunker": 1,
            "container": 1,
            "greenhouse": 1,
            "roof": 1,
            "house": 2,
            "detached": 2,
            "semidetached_house": 2,
            "bungalow": 1,
            "terrace": 2,
        }
    )
    #: S3DB outline rule: an outline whose building:parts cover at least this fraction of its area is not
    #: drawn (its parts are). 0 = strict S3DB (any part hides the outline); the default follows OSM2World's
    #: 90 % rule so a building with one small part on its roof is still drawn.
    outline_part_coverage: float = 0.9
    #: LOD3 windows and doors: "box" = a closed 12-triangle frame box per opening standing out of the wall;
    #: "panel" = only its 2-triangle front face. On Liechtenstein boxes make LOD3 8.9 M triangles instead of
    #: 1.8 M and the lod stage about 4× slower (20 s against 4.7 s, measured by hand at 7f4c184).
    lod3_openings: str = "panel"
    #: Worker processes building the meshes, one batch of buildings per Dask task (0: one per CPU core but the
    #: one the database's COPY needs, at most 4; 1 builds them in the stage's own process, the default on 2
    #: cores, where it is the faster). The meshes are the same whatever the count.
    lod_workers: int = 0
    #: Buildings per batch (one Dask task); the meshes are the same whatever the size.
    lod_batch_size: int = 2000
    #: A batch still being built after this many seconds is hung, not slow (Liechtenstein's 2,000-building
    #: batches take ~0.5 s): its worker is stopped and its buildings recorded as rejects (lod_hung).
    lod_batch_timeout_s: float = 600.0

    # --- tiles ----------------------------------------------------------------------------------------------
    #: Quadtree budget: a cell is split while it holds more features (buildings + parts) than this ...
    tile_max_features: int = 500
    #: ... or more triangles than this.
    tile_max_triangles: int = 100_000
    #: Deepest quadtree level (cells there are leaves whatever their load).
    tile_max_level: int = 16

    # --- generalize (tolerances per level: gen.tolerance in sql/gen/tolerance.sql) --------------------------
    #: Largest relative change of a footprint's area simplification may make; beyond it the original is kept.
    gen_max_area_change: float = 0.1
    #: LOD2 meshes with at least this many triangles are decimated for the LOD2 band ...
    gen_decimate_min_triangles: int = 64
    #: ... by this fraction of their triangles (fast-simplification), kept only within gen.tolerance(3).
    gen_decimate_reduction: float = 0.5
    #: Features per footprint or decimation batch, at most: a batch is the largest subtree of the tile quadtree
    #: holding no more (gen.batch_units), so an edit changes the batches where it is and an update copies the
    #: others' rows from the last run (gen.unit_input).
    #: Smaller batches cost a full run a little (Liechtenstein's footprints and decimation: 17.6 s at 2,000,
    #: 18.5 s at 1,000, 20.1 s at 500) and an update less: it computes the few batches an edit touches again.
    gen_batch_features: int = 500
    #: Worker processes for the footprint and decimation batches, one batch per Dask task (0: one per CPU core,
    #: at most 4; 1 runs them in the stage's own process). The rows are the same whatever the count.
    gen_workers: int = 0
    #: A batch still running after this many seconds is hung, not slow (Liechtenstein's 2,000-building batches
    #: take ~2 s): its buildings are kept as mapped (their LOD2 meshes), saying so in gen.footprint.status.
    gen_batch_timeout_s: float = 600.0

    # --- landmarks (saliency weights: 0 leaves a measure out; etl/landmarks/stage.py) --------------------------
    #: Weight of the height (the thesis' proof of concept used height alone).
    lm_w_height: float = 1.0
    #: Weight of the volume of the building's meshes.
    lm_w_volume: float = 0.5
    #: Weight of the footprint area.
    lm_w_area: float = 0.25
    #: Weight of the height relative to the neighbours within lm_neighbour_radius_m.
    lm_w_relative_height: float = 0.5
    #: Weight of the footprint's shape distinctiveness against its neighbours.
    lm_w_shape: float = 0.25
    #: Weight of the semantic tags (place of worship, cathedral/church/tower, tourism, historic, heritage, ...).
    lm_w_semantic: float = 1.5
    #: Neighbourhood (m) of the relative measures.
    lm_neighbour_radius_m: float = 150.0
    #: At most this fraction of the buildings are landmarks: the highest voting-hierarchy levels that fit.
    lm_max_fraction: float = 0.01
    #: Exaggeration (api.landmark_scale): a landmark starts to grow where its height would drop below this many
    #: pixels of a 1080 px high, 60° view ...
    lm_min_screen_px: float = 48.0
    #: ... by this factor each time the distance grows by it (the predefined intervals) ...
    lm_scale_step: float = 1.5
    #: ... up to this scale for the top of the hierarchy (the lowest landmark level gets a share of it).
    lm_max_scale: float = 3.0

    # --- textures (etl/textures/stage.py; the resolution rule is etl/textures/atlas.py texels_per_metre) -------
    #: Largest atlas page side in texels (the thesis' 512; a power of two, 16 to 4096). Pages are cropped to
    #: the smallest power-of-two rectangle that holds them, and a tile gets as many pages as its charts need.
    tex_page_size: int = 512
    #: Screen pixels per texel at the nearest distance a tile is drawn from (1 = no magnification there).
    tex_px_per_texel: float = 1.0
    #: Vertical field of view (degrees) and ...
    tex_fov_deg: float = 60.0
    #: ... screen height (pixels) of the view the resolution rule assumes (CesiumJS' default view, full HD).
    tex_screen_height: int = 1080
    #: The client's maximum screen-space error (CesiumJS' default 16): a tile with geometric error e is drawn
    #: from e × screen_height / (2 tan(fov/2) × max_sse) on, so it needs max_sse / (e × px_per_texel) texels/m.
    tex_max_sse: float = 16.0
    #: Cap on texels per metre, the resolution of the leaves (geometric error 0: seen from any distance) and of
    #: every tile whose rule asks for more. 2 texels/m (50 cm) shows storeys and windows; each doubling
    #: quadruples the stage's time and bytes.
    tex_max_texels_per_metre: float = 2.0
    #: Gutter texels around each chart (bilinear filtering and the first mip levels never mix in a
    #: neighbour) at the cap; coarser tiles get less (etl/textures/tile.py padding_for).
    tex_padding: int = 2
    #: Charts with fewer texels than this (or thinner than 2) are drawn in their flat tagged colour.
    tex_min_chart_texels: int = 16
    #: Roofs with more planar faces than this get xatlas charts instead of one chart per face.
    tex_xatlas_min_planes: int = 24
    #: Atlas packer: shelf (measured better on rectangles: benchmarks/atlas_compare.py) or xatlas.
    tex_packer: str = "shelf"
    #: WebP quality (0-100) of the atlas pages.
    tex_quality: int = 90
    #: Basis Universal ETC1S quality (basisu -q, 1-255: the codebook sizes) of the KTX2 pages. 64: the PSNR of
    #: 128 (35.2 dB on Liechtenstein's pages; ETC1S' block format sets it) for 0.81x the bytes.
    tex_ktx2_quality: int = 64
    #: basisu -comp_level (0-6): encoder effort.
    tex_ktx2_comp_level: int = 1
    #: A page basisu has not encoded after this many seconds is refused (tex.failure ktx2_encode_failed).
    tex_ktx2_timeout_s: float = 60.0
    #: Worker processes (0: one per CPU core, at most 4; 1 runs in the stage's own process).
    tex_workers: int = 0
    #: A unit of work (a LOD2 tile and its leaves) still running after this many seconds is hung, not slow (the
    #: slowest of Liechtenstein's 66 takes 3.4 s): its worker is stopped and its features recorded as failed.
    tex_unit_timeout_s: float = 600.0

    # --- export ---------------------------------------------------------------------------------------------
    #: Ellipsoidal height (m) at which ground level is placed: no terrain is used, so 0 puts buildings on
    #: CesiumJS's plain WGS84 globe.
    base_height_m: float = 0.0
    #: Dask worker processes writing the tiles' glbs, one tile per task (0: threads of the export's process, one
    #: per core, at most 4, faster on 2 cores, or the cluster CITYLOD_DASK_SCHEDULER names; 1: the export's own
    #: process, one tile at a time). The bytes are the same whatever the count.
    export_workers: int = 0
    #: A tile still being written after this many seconds is hung, not slow: the export stops with that tile
    #: named and the tileset already in place is kept.
    export_tile_timeout_s: float = 600.0
    #: Generations of each published tileset (pub.*) kept in the database: the live one and the ones before it,
    #: whose bytes a later generation often shares. Older ones and the blobs only they named are deleted.
    publish_keep: int = 2

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None) -> Settings:
        env = dict(os.environ if env is None else env)
        kwargs: dict[str, Any] = {}  # each value of its field's type (its default's)
        for f in dataclasses.fields(cls):
            key = cls.env_name(f.name)
            if key not in env:
                continue
            raw = env[key]
            default = getattr(cls(), f.name)
            if isinstance(default, bool):
                kwargs[f.name] = raw.lower() in ("1", "true", "yes", "on")
            elif isinstance(default, int):
                kwargs[f.name] = int(raw)
            elif isinstance(default, float):
                kwargs[f.name] = float(raw)
            elif isinstance(default, str):
                kwargs[f.name] = raw
            else:
                raise ValueError(f"{key} cannot be set from the environment")
        return cls(**kwargs)

    def as_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)

    @staticmethod
    def env_name(field_name: str) -> str:
        """The environment variable that overrides a setting."""
        return f"CITYLOD_{field_name.upper()}"

    def describe(self, env: dict[str, str] | None = None) -> list[str]:
        """Every setting as a line a shell reads: ``CITYLOD_<FIELD>=<value>``, each followed by whether the
        environment set it (``python -m etl config``)."""
        env = dict(os.environ if env is None else env)
        out = []
        for f in dataclasses.fields(self):
            key = self.env_name(f.name)
            value = getattr(self, f.name)
            if isinstance(value, dict | list | tuple):  # from_env reads scalars only
                out.append(f"# {key}={shlex.quote(json.dumps(value))}  # not settable from the environment")
                continue
            out.append(f"{key}={shlex.quote(str(value))}  # {'set in the environment' if key in env else 'default'}")
        return out
