"""LIDAR scan (paired lines, one broadcast) against a ray-by-ray, box-by-box loop."""

from __future__ import annotations

import math

import pytest
import torch

from torchpark.sim.geometry import OrientedBoxes, oriented_boxes, ray_box_distance
from torchpark.sim.lidar import lidar_scan, line_rotation


@pytest.mark.parametrize("n_rays", [16, 12, 7, 4, 2, 1])
def test_scan_matches_per_ray_loop(n_rays, layout):
    gen = torch.Generator().manual_seed(0)
    n = 64
    boxes = layout.obstacles
    frame = OrientedBoxes(*(t.contiguous() for t in oriented_boxes(boxes)))
    valid = torch.rand(n, boxes.shape[0], generator=gen) < 0.6
    x = torch.rand(n, generator=gen) * layout.width
    y = torch.rand(n, generator=gen) * layout.height
    psi = (torch.rand(n, generator=gen) * 2 - 1) * math.pi
    got = lidar_scan(x, y, torch.cos(psi), torch.sin(psi), line_rotation(n_rays), frame,
                     valid.float(), n_rays, 20.0)
    assert got.shape == (n, n_rays)
    # Each ray against each box on its own (the slab test of one box), the nearest present
    # box's distance: all (car, ray, box) triples at once, as a loop over them would give.
    angles = psi[:, None] + torch.tensor([2 * math.pi * k / n_rays for k in range(n_rays)])
    origins = torch.stack((x, y), -1)[:, None, None]
    d = ray_box_distance(origins, angles[..., None], boxes[None, None], 20.0)  # (n, K, M)
    nearest = d.masked_fill(~valid[:, None], math.inf).amin(-1)
    torch.testing.assert_close(got, nearest, rtol=0, atol=2e-4)


def test_scan_sees_max_range_in_the_open_and_zero_inside_a_box():
    frame = oriented_boxes(torch.tensor([[0.0, 0.0, 0.3, 1.0, 1.0]]))
    valid = torch.tensor([[True], [True], [False]])
    x, y = torch.tensor([0.2, 100.0, 0.2]), torch.zeros(3)
    out = lidar_scan(x, y, torch.ones(3), torch.zeros(3), line_rotation(16), frame, valid.float(),
                     16, 20.0)
    assert (out[0] == 0).all() and (out[1] == 20).all() and (out[2] == 20).all()


def test_rays_along_an_edge_line_from_on_it_hit_the_box():
    """Heading 0 exactly, origin exactly on the box's lower edge line, 3 m before it: the rays
    along that line (a zero direction component in the box frame, reciprocal inf) see the box
    ahead at 3 m and nothing behind; never NaN."""
    frame = oriented_boxes(torch.tensor([[5.0, 1.0, 0.0, 2.0, 1.0]]))  # x in [3, 7], y in [0, 2]
    out = lidar_scan(torch.zeros(1), torch.zeros(1), torch.ones(1), torch.zeros(1),
                     line_rotation(16), frame, torch.ones(1, 1), 16, 20.0)
    assert not out.isnan().any()
    assert out[0, 0] == 3.0 and out[0, 8] == 20.0  # ahead along the edge; behind: nothing
    assert out[0, 4] == 20.0  # straight up (cos(pi/2) != 0 in float32): misses the box
