"""pytest runs the notebooks (nbmake) with small sizes: the kernels inherit this variable."""

import os

os.environ.setdefault("TORCHPARK_QUICK", "1")
