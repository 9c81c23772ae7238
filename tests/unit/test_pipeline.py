"""The stage graph (core/pipeline.py) is written once and everything derives from it: the make targets, the
update's steps, the producers of each stage, the subcommands of python -m etl."""

from __future__ import annotations

import argparse
import re
import subprocess

from core.changes import PRODUCERS
from core.pipeline import GRAPH, STAGES, ancestors, make_rules, producers, update_steps
from tests.conftest import REPO


def test_the_graph_is_in_pipeline_order_and_reads_only_earlier_stages() -> None:
    order = list(GRAPH)
    assert order[0] == "ingest" and order[-1] == "export"
    for stage, reads in GRAPH.items():
        assert all(order.index(r) < order.index(stage) for r in reads), stage
    assert ancestors(GRAPH["tiles"]) == ["ingest", "lod"]
    assert ancestors(GRAPH["generalize"]) == ["ingest", "lod", "landmarks", "tiles"]
    assert ancestors(GRAPH["export"]) == order[:-1]
    assert PRODUCERS["textures"] == producers("textures") == ("ingest", "lod", "landmarks", "tiles", "generalize")


def test_an_update_runs_at_once_only_stages_that_read_nothing_of_each_other() -> None:
    steps = update_steps()
    assert [s for step in steps for s in step] == list(GRAPH)[1:-1]  # between ingest and the export, in order
    for step in steps:
        for stage in step:
            assert not set(ancestors(GRAPH[stage])) & set(step), (stage, step)
    assert steps == [("lod",), ("landmarks", "tiles"), ("generalize",), ("textures",)]


def test_make_targets_come_from_the_graph() -> None:
    rules = make_rules()
    for s in STAGES:
        deps = re.search(rf"^{s.name}: (.*?) ## ", rules, re.M)
        assert deps, s.name
        wanted = " ".join(r for r in GRAPH if r in s.reads) if s.reads else "migrate $(OSM)"
        assert wanted in deps.group(1), (s.name, deps.group(1))
        assert f"\t$(PY) -m etl {s.name} $(ARGS_{s.name}) $(call STALE,{s.name})" in rules
    # the Makefile includes the rules made from the graph and writes no stage rule of its own
    makefile = (REPO / "Makefile").read_text()
    assert "include $(STAGES_MK)" in makefile and "python3 -m core.pipeline make" in makefile
    assert not re.search(rf"^({'|'.join(GRAPH)}):", makefile, re.M)


def test_make_dry_runs_a_stage_after_the_stages_it_reads(tmp_path) -> None:
    # make -n on the real Makefile: the generated targets order the chain (nothing runs)
    out = subprocess.run(
        ["make", "-n", "-C", str(REPO), "generalize", "PY=echo"], capture_output=True, text=True, check=True
    ).stdout
    # a clone without the demo extract fetches it first; that is a step, not a stage
    ran = [m.group(1) for m in re.finditer(r"^echo -m etl ([\w-]+)", out, re.M) if m.group(1) != "fetch-demo"]
    assert ran[-6:] == ["migrate", "ingest", "lod", "landmarks", "tiles", "generalize"], out


def test_every_stage_is_a_subcommand_with_its_help() -> None:
    from etl.__main__ import parser

    sub = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    assert {s.name: s.does for s in STAGES}.items() <= helps.items()
