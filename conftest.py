"""Loaded by pytest before any test module, for the tests, the notebooks and the README.

Inductor's compile cache, one per CPU kernel set: torch keys the C++ it caches by neither,
so a cache filled under one ``ATEN_CPU_CAPABILITY`` fails to compile under another
("at::vec has not been declared"). Set here, before anything imports torchrl (whose import
fixes the cache directory); a cache the user chose is left alone.
"""

import getpass
import os
import tempfile

import torch

os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", os.path.join(
    tempfile.gettempdir(),
    f"torchinductor_{getpass.getuser()}_{torch.backends.cpu.get_cpu_capability().lower()}"))
