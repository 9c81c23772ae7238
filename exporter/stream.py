"""How a tileset is encoded for the stream: one value object the export, the DB server and the CLI share.

* ``geometry``: ``compact`` = KHR_mesh_quantization + KHR_meshopt_compression (meshoptimizer, vertex codec
  version 1: CesiumJS 1.145 and loaders.gl 4.5 here decode it, as does three.js' GLTFLoader),
  ``compact-ext`` = the same geometry through EXT_meshopt_compression (codec version 0, 11-29 % larger streams:
  for loaders that know only the EXT extension), ``plain`` = float32 attributes as before (for clients without
  meshopt).
* ``textures``: ``ktx2`` = KHR_texture_basisu (Basis Universal, full mip chains), ``webp`` = EXT_texture_webp.
* ``tiling``: ``implicit`` = 3D Tiles 1.1 implicitTiling with subtree files, ``explicit`` = every tile in
  tileset.json.
* ``tables`` (compact geometry): ``plain`` = the EXT_structural_metadata property tables' views uncompressed,
  which tools that read metadata without a meshopt decoder (the CesiumGS 3d-tiles-validator) can read;
  ``meshopt`` = compressed like the geometry (allowed by the extension; ~7 % smaller streams).
The defaults are the compact choices; every combination is a valid 3D Tiles 1.1 tileset.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

from exporter import meshopt

Geometry = Literal["compact", "compact-ext", "plain"]
Textures = Literal["ktx2", "webp"]
Tiling = Literal["implicit", "explicit"]
Tables = Literal["plain", "meshopt"]

GEOMETRY: tuple[Geometry, ...] = ("compact", "compact-ext", "plain")
TEXTURES: tuple[Textures, ...] = ("ktx2", "webp")
TILING: tuple[Tiling, ...] = ("implicit", "explicit")
TABLES: tuple[Tables, ...] = ("plain", "meshopt")


@dataclass(frozen=True)
class StreamOptions:
    geometry: Geometry = "compact"
    textures: Textures = "ktx2"
    tiling: Tiling = "implicit"
    tables: Tables = "plain"

    def __post_init__(self) -> None:
        for name, allowed in (("geometry", GEOMETRY), ("textures", TEXTURES), ("tiling", TILING), ("tables", TABLES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, not {getattr(self, name)!r}")

    def as_dict(self) -> dict[str, str]:
        return asdict(self)

    @property
    def compact(self) -> bool:
        """Quantized, meshopt-compressed geometry (either extension)."""
        return self.geometry != "plain"

    @property
    def meshopt_extension(self) -> str:
        """The meshopt extension compact glbs are written with."""
        return meshopt.EXT if self.geometry == "compact-ext" else meshopt.KHR


#: today's uncompressed stream (float32 geometry, WebP pages, every tile in tileset.json)
PLAIN = StreamOptions(geometry="plain", textures="webp", tiling="explicit")
#: the default: quantized meshopt geometry, KTX2 pages, implicit tiling
COMPACT = StreamOptions()
