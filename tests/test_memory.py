"""Sizes refused before they are allocated (torchpark.memory): the env's estimate against
the device's free memory, and the demo's one line."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import torchpark.memory as memory
from torchpark import ParkingEnv
from torchpark.__main__ import main as demo


def test_a_size_the_device_cannot_hold_is_refused_in_one_line(monkeypatch):
    """ParkingEnv and the demo estimate their memory before they allocate it."""
    monkeypatch.setattr(memory, "free_bytes", lambda device: 4 * 2**30)  # a 4 GB machine
    with pytest.raises(memory.TooLarge, match=r"ParkingEnv\(num_envs=1000000\) needs about "
                                              r"\d+\.\d GiB on cpu, which has 4\.0 GiB free"):
        ParkingEnv(10**6)
    with pytest.raises(memory.TooLarge, match=r"blocks_ahead=256\) needs about"):
        ParkingEnv(10**5, reset_in_step=True, blocks_ahead=256)
    ParkingEnv(1000, reset_in_step=True, blocks_ahead=256)  # what fits is built
    with pytest.raises(SystemExit) as refused:
        demo(["--eager", "--num-envs", "1000000"])
    assert refused.value.code == 2
    assert memory.free_bytes(torch.device("cpu")) == 4 * 2**30


@pytest.mark.skipif(not Path("/proc/meminfo").exists(), reason="reads Linux's /proc/meminfo")
def test_the_host_tells_its_free_memory():
    total = int(Path("/proc/meminfo").read_text().split()[1]) * 1024  # MemTotal, first
    free = memory.free_bytes(torch.device("cpu"))
    assert isinstance(free, int) and 0 < free <= total


def test_a_planner_grid_larger_than_memory_is_refused_before_it_is_built(monkeypatch):
    from torchpark.config import ParkingConfig
    from torchpark.experts.config import PlannerConfig
    from torchpark.experts.planner import build_planner
    from torchpark.sim.layout import build_layout

    cfg = ParkingConfig()
    layout = build_layout(cfg.lot, cfg.vehicle, "cpu")
    allocated = []
    monkeypatch.setattr(torch, "meshgrid", lambda *a, **k: allocated.append(a))  # the grid
    with pytest.raises(memory.TooLarge, match=r"PlannerConfig\(cell=0\.01, headings=64\): its "
                                              r"grid of 1,019,068,800 cells needs about"):
        build_planner(layout, cfg.vehicle, PlannerConfig(cell=0.01))
    assert not allocated


def test_the_demo_says_an_out_of_memory_while_stepping_in_one_line(monkeypatch, capsys):
    """The estimate is no guarantee: an allocation that fails while stepping is one line."""
    import torchpark.__main__ as cli

    def exhausted(env, steps):
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 24.00 GiB")

    monkeypatch.setattr(cli, "drive", exhausted)
    with pytest.raises(SystemExit) as refused:
        demo(["--eager", "--num-envs", "8"])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "Traceback" not in err
    assert err.startswith("python -m torchpark: error: --num-envs 8 ran out of memory while "
                          "stepping (CUDA out of memory."), err
