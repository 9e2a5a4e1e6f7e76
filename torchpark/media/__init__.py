"""Pictures and videos of lots and rollouts (Pillow, imageio): imported on first use, so the
env itself needs neither (``pip install torchpark[media]``)."""
