"""How a tileset is encoded for the stream: one value object the export, the DB server and the CLI share.

* ``geometry``: ``compact`` = KHR_mesh_quantization + EXT_meshopt_compression (meshoptimizer), ``plain`` =
  float32 attributes as before (for clients without meshopt).
* ``textures``: ``ktx2`` = KHR_texture_basisu (Basis Universal, full mip chains), ``webp`` = EXT_texture_webp.
* ``tiling``: ``implicit`` = 3D Tiles 1.1 implicitTiling with subtree files, ``explicit`` = every tile in
  tileset.json.
The defaults are the compact choices; every combination is a valid 3D Tiles 1.1 tileset.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

Geometry = Literal["compact", "plain"]
Textures = Literal["ktx2", "webp"]
Tiling = Literal["implicit", "explicit"]

GEOMETRY: tuple[Geometry, ...] = ("compact", "plain")
TEXTURES: tuple[Textures, ...] = ("ktx2", "webp")
TILING: tuple[Tiling, ...] = ("implicit", "explicit")


@dataclass(frozen=True)
class StreamOptions:
    geometry: Geometry = "compact"
    textures: Textures = "ktx2"
    tiling: Tiling = "implicit"

    def __post_init__(self) -> None:
        for name, allowed in (("geometry", GEOMETRY), ("textures", TEXTURES), ("tiling", TILING)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, not {getattr(self, name)!r}")

    def as_dict(self) -> dict[str, str]:
        return asdict(self)


#: today's uncompressed stream (float32 geometry, WebP pages, every tile in tileset.json)
PLAIN = StreamOptions(geometry="plain", textures="webp", tiling="explicit")
#: the default: quantized meshopt geometry, KTX2 pages, implicit tiling
COMPACT = StreamOptions()
