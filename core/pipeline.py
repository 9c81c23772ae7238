"""The stage graph, written once: every stage in pipeline order, the stages whose tables it reads, the module
that runs it and what it turns into what.

Everything else derives from it: the make targets and their help (``python3 -m core.pipeline make`` writes
them; the Makefile includes the result), the subcommands of ``python -m etl``, staleness (etl/staleness.py:
a stage is stale when a stage it reads ran again), which runs change what a stage reads (``producers``,
core/changes.py) and the steps an update runs (``update_steps``). Standard library only, so make can run it
with the system's python3 before the venv exists.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass


@dataclass(frozen=True)
class Stage:
    name: str
    #: the stages whose tables it reads
    reads: tuple[str, ...]
    #: the module whose ``run(ctx)`` runs it (core/stage.py); its import closure is the stage's Python code
    module: str
    #: tables in -> tables out, one line (make help, python -m etl --help)
    does: str
    #: the make variables it takes, for make help
    usage: str = ""


STAGES = (
    Stage("ingest", (), "etl.ingest.stage", "OSM file -> osm.building (+ osm.reject)", "OSM=path"),
    Stage("lod", ("ingest",), "etl.lod.stage", "osm.building -> lod.building_mesh (LOD1, LOD2, LOD3 solids)"),
    # osm.building, lod.building_mesh
    Stage(
        "landmarks",
        ("lod",),
        "etl.landmarks.stage",
        "lod.building_mesh -> lm.building (saliency, voting hierarchy) and osm.building.protected",
    ),
    Stage("tiles", ("lod",), "etl.tiles.stage", "lod.building_mesh -> tiles.tile quadtree"),
    # tiles.*, the meshes, osm.building.protected (set by landmarks)
    Stage(
        "generalize",
        ("tiles", "landmarks"),
        "etl.generalize.stage",
        "tiles + meshes -> gen.* (simplified, decimated, blocks) and tile errors",
    ),
    # tiles.tile errors, api.buildings_for_tile (gen.*, lm.building)
    Stage(
        "textures",
        ("generalize",),
        "etl.textures.stage",
        "tiles -> tex.page atlases (procedural facades and roofs) and tex.feature_uv",
    ),
    # api.buildings_for_tile, lm.building, tex.*; a one-LOD export (--lod) reads up to generalize
    Stage(
        "export", ("textures",), "exporter.export", "tiles -> 3D Tiles 1.1 (tileset.json + glb)", "OUT=dir [LOD=1|2|3]"
    ),
)
BY_NAME = {s.name: s for s in STAGES}
#: stage -> the stages whose tables it reads, in pipeline order
GRAPH: dict[str, tuple[str, ...]] = {s.name: s.reads for s in STAGES}
#: the stage each full run starts from: it reads a file, not tables
FIRST = STAGES[0].name
#: the stage that writes outside the database (a tileset directory)
LAST = STAGES[-1].name


def ancestors(reads: tuple[str, ...] | list[str]) -> list[str]:
    """Every stage ``reads`` names and every stage those read, in pipeline order."""
    seen: set[str] = set()
    todo = list(reads)
    while todo:
        s = todo.pop()
        if s not in seen:
            seen.add(s)
            todo.extend(GRAPH[s])
    return [s for s in GRAPH if s in seen]


def producers(stage: str) -> tuple[str, ...]:
    """The stages whose runs change what ``stage`` reads, directly or through another."""
    return tuple(ancestors(GRAPH[stage]))


def depth(stage: str) -> int:
    """0 for the first stage, else one more than the deepest stage it reads."""
    return 1 + max((depth(s) for s in GRAPH[stage]), default=-1)


def update_steps() -> list[tuple[str, ...]]:
    """The stages an update runs after ingest and before the export, by depth: the stages of a step read none
    of each other's tables, so they run side by side."""
    inner = [s.name for s in STAGES if s.name not in (FIRST, LAST)]
    depths = sorted({depth(s) for s in inner})
    return [tuple(s for s in inner if depth(s) == d) for d in depths]


def make_rules() -> str:
    """The make target of every stage: it depends on the stages it reads (the first on ``migrate`` and its input
    ``$(OSM)``) and runs ``python -m etl <stage>`` with --if-stale; ``ARGS_<stage>`` gives a stage's own
    arguments and ``READS_<stage>``, when set, replaces what its target depends on (a one-LOD export reads up to
    generalize)."""
    out = ["# Made by `python3 -m core.pipeline make` from the stage graph, core/pipeline.py: edit that.", ""]
    for s in STAGES:
        reads = " ".join(r for r in GRAPH if r in s.reads) if s.reads else "migrate $(OSM)"  # in pipeline order
        deps = f"$(or $(READS_{s.name}),{reads})" if s.reads else reads
        usage = f"{s.usage}: " if s.usage else ""
        out += [
            f"{s.name}: {deps} ## {usage}{s.does}",
            f"\t$(PY) -m etl {s.name} $(ARGS_{s.name}) $(call STALE,{s.name})",
            "",
        ]
    out.append(f".PHONY: {' '.join(s.name for s in STAGES)}")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    if sys.argv[1:] != ["make"]:
        sys.exit("usage: python3 -m core.pipeline make")
    sys.stdout.write(make_rules())
