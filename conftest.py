"""Loaded by pytest before any test module, for the tests, the notebooks and the README.

The notebooks and the README's blocks are marked ``slow`` (whole workflows, seconds each):
``python -m pytest -m "not slow"`` is the edit-test loop, the plain command the whole suite.

Inductor's compile cache, one per CPU kernel set: torch keys the C++ it caches by neither,
so a cache filled under one ``ATEN_CPU_CAPABILITY`` fails to compile under another
("at::vec has not been declared"). Set here, before anything imports torchrl (whose import
fixes the cache directory); a cache the user chose is left alone.
"""

import getpass
import os
import tempfile

import pytest
import torch

os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", os.path.join(
    tempfile.gettempdir(),
    f"torchinductor_{getpass.getuser()}_{torch.backends.cpu.get_cpu_capability().lower()}"))

# A pytest-xdist worker (``-n``) computes on one thread, as do the processes it starts (they
# inherit the variable): workers already fill the cores, and two workers' thread pools on
# two cores spend more time waiting on each other than computing.
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["OMP_NUM_THREADS"] = "1"
    torch.set_num_threads(1)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.suffix in (".ipynb", ".md"):
            item.add_marker(pytest.mark.slow)
