"""`warpshade run` of a data-driven graph gives the same output with and without a scheduler:
in this process, in local worker processes and on a Dask LocalCluster (training frames and
ground-truth frames are the tasks). Each run has its own empty cache, so every run computes."""

import json

import numpy as np
import pytest

from warpshade.cli import main

GRAPH = """
[graph]
name = "bend_dd"
scene = "{scene}"
output = "shade.radiance"
frames = "0:6"

[validate]
frames = [3]
samples = 64

[[stage]]
name = "data"
type = "datadriven.data"
frames = "0:60:5"
order = 2
samples = 32

[[stage]]
name = "fit"
type = "datadriven.fit"
reduction = "reduced"
validation = 0.0
ka = 2
kv = 8

[[stage]]
name = "transfer"
type = "datadriven.transfer"
order = 2

[[stage]]
name = "shade"
type = "prt.shade"
order = 2
"""


def _run(tmp_path, monkeypatch, name, scheduler):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / f"cache-{name}"))
    monkeypatch.delenv("WARPSHADE_SCHEDULER", raising=False)
    graph = tmp_path / "bend_dd.toml"
    graph.write_text(GRAPH.format(scene="bundled:bend"))
    out = tmp_path / f"out-{name}"
    args = ["run", str(graph), "--out", str(out), "--validate", "--no-previews"]
    if scheduler is not None:
        args += ["--scheduler", scheduler]
    assert main(args) == 0
    report = json.loads((out / "bend_dd.json").read_text())
    return (out / "bend_dd.usda").read_bytes(), report


def test_run_is_the_same_with_and_without_a_scheduler(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    serial_usd, serial = _run(tmp_path, monkeypatch, "serial", "serial")
    local_usd, local = _run(tmp_path, monkeypatch, "local", "local:2")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as cluster:
        dask_usd, dask = _run(tmp_path, monkeypatch, "dask", cluster.scheduler_address)
    assert serial_usd == local_usd == dask_usd
    for other in (local, dask):
        assert other["error"]["mean"]["rel_rms"] == serial["error"]["mean"]["rel_rms"]
        assert other["error"]["samples"] == 64
    assert np.isfinite(serial["error"]["mean"]["rel_rms"])


def test_bad_scheduler_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / "cache"))
    graph = tmp_path / "bend_dd.toml"
    graph.write_text(GRAPH.format(scene="bundled:bend"))
    assert main(["run", str(graph), "--out", str(tmp_path / "o"), "--scheduler", "nowhere:1"]) == 2
    err = capsys.readouterr().err
    assert "--scheduler" in err and "nowhere:1" in err
