"""Geometry against shapely (an independent reference) and hypothesis edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.conftest import polygon, polygons
from torchpark.sim.geometry import box_corners, boxes_overlap, ray_box_distance, wrap_angle

GAP = 1e-4  # 0.1 mm


def random_boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack([
        rng.uniform(-10, 10, n), rng.uniform(-10, 10, n), rng.uniform(-math.pi, math.pi, n),
        rng.uniform(0.05, 4.0, n), rng.uniform(0.05, 2.0, n),
    ])


def contact_pairs(rng: np.random.Generator, n: int, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs where b touches a with its half extents grown by ``margin``: with margin > 0 the
    boxes are apart by 0.1 to 0.14 mm, with margin < 0 they overlap by at least 0.1 mm."""
    a, b = random_boxes(rng, n), random_boxes(rng, n)
    theta = rng.uniform(-math.pi, math.pi, n)
    direction = np.column_stack([np.cos(theta), np.sin(theta)])
    grown = a.copy()
    grown[:, 3:] += margin
    target = polygons(grown)
    # Bisection of every pair's distance at once: b centred on a's centre overlaps; 30 m
    # away it is clear.
    lo, hi = np.zeros(n), np.full(n, 30.0)
    for _ in range(60):
        mid = (lo + hi) / 2.0
        b[:, :2] = a[:, :2] + mid[:, None] * direction
        hit = shapely.intersects(target, polygons(b))
        lo, hi = np.where(hit, mid, lo), np.where(hit, hi, mid)
    b[:, :2] = a[:, :2] + lo[:, None] * direction  # touching the grown box, from inside
    return a, b


def shapely_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return shapely.intersects(polygons(a), polygons(b))


def test_corners_match_shapely_area_and_orientation():
    rng = np.random.default_rng(0)
    boxes = random_boxes(rng, 200)
    corners = box_corners(torch.tensor(boxes)).numpy()
    for box, quad in zip(boxes, corners, strict=True):
        poly = shapely.Polygon(quad)
        assert poly.is_valid and poly.exterior.is_ccw
        assert poly.area == pytest.approx(4 * box[3] * box[4], rel=1e-9)
        assert poly.symmetric_difference(polygon(box)).area < 1e-9


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_overlap_agrees_with_shapely_on_random_and_near_touching_pairs(dtype):
    rng = np.random.default_rng(1)
    sets = [
        (random_boxes(rng, 7000), random_boxes(rng, 7000)),
        contact_pairs(rng, 1500, +GAP),  # 0.1 mm apart
        contact_pairs(rng, 1500, -GAP),  # 0.1 mm overlap
    ]
    a = np.concatenate([s[0] for s in sets])
    b = np.concatenate([s[1] for s in sets])
    # Round the inputs to the dtype under test, so shapely judges the very same boxes.
    ta, tb = torch.tensor(a, dtype=dtype), torch.tensor(b, dtype=dtype)
    expected = shapely_overlap(ta.double().numpy(), tb.double().numpy())
    got = boxes_overlap(ta, tb).numpy()
    assert len(got) == 10_000
    assert expected[7000:8500].sum() == 0 and expected[8500:].all()  # the contact sets are real
    mismatches = np.flatnonzero(got != expected)
    assert mismatches.size == 0, f"{mismatches.size} mismatches, first {a[mismatches[:3]]}"
    assert torch.equal(boxes_overlap(tb, ta), boxes_overlap(ta, tb))  # symmetric


def shapely_ray(origin: np.ndarray, angle: float, box: np.ndarray, max_range: float) -> float:
    poly = polygon(box)
    start = shapely.Point(origin)
    if poly.covers(start):
        return 0.0
    end = origin + max_range * np.array([math.cos(angle), math.sin(angle)])
    hit = poly.intersection(shapely.LineString([origin, end]))
    return max_range if hit.is_empty else min(start.distance(hit), max_range)


def grazing(origin: np.ndarray, angle: float, box: np.ndarray, tol: float) -> bool:
    """Whether the ray's line passes within ``tol`` of a corner: there float32 may round a
    hit into a miss, and no reference decides it better."""
    d = np.array([math.cos(angle), math.sin(angle)])
    corners = box_corners(torch.tensor(box)).numpy() - origin
    return bool(np.any(np.abs(corners[:, 0] * d[1] - corners[:, 1] * d[0]) < tol))


def test_ray_distance_agrees_with_shapely():
    rng = np.random.default_rng(2)
    n = 4000
    boxes = random_boxes(rng, n)
    origins = rng.uniform(-12, 12, (n, 2))
    # Aim half of the rays at the box, so most of them hit.
    aim = np.arctan2(boxes[:, 1] - origins[:, 1], boxes[:, 0] - origins[:, 0])
    angles = np.where(rng.random(n) < 0.5, aim + rng.normal(0, 0.2, n),
                      rng.uniform(-math.pi, math.pi, n))
    max_range = 20.0
    t32 = {k: torch.tensor(v, dtype=torch.float32) for k, v in
           (("o", origins), ("a", angles), ("b", boxes))}
    got = ray_box_distance(t32["o"], t32["a"], t32["b"], max_range).numpy()
    o64, a64, b64 = (t32[k].double().numpy() for k in "oab")
    expected = np.array([shapely_ray(o64[i], a64[i], b64[i], max_range) for i in range(n)])
    keep = np.array([not grazing(o64[i], a64[i], b64[i], 1e-3) for i in range(n)])
    assert keep.mean() > 0.95 and (expected[keep] < max_range).mean() > 0.3
    np.testing.assert_allclose(got[keep], expected[keep], atol=1e-4)


def test_ray_distance_is_max_range_beyond_range_and_zero_inside():
    box = torch.tensor([10.0, 0.0, 0.0, 1.0, 1.0])
    origin = torch.tensor([0.0, 0.0])
    assert ray_box_distance(origin, torch.tensor(0.0), box, 20.0).item() == pytest.approx(9.0)
    assert ray_box_distance(origin, torch.tensor(0.0), box, 5.0) == 5.0
    assert ray_box_distance(origin, torch.tensor(math.pi), box, 20.0) == 20.0
    assert ray_box_distance(torch.tensor([10.5, 0.2]), torch.tensor(1.0), box, 20.0) == 0.0


finite = st.floats(-50, 50)
half = st.floats(0.01, 10)


# Multiples of 1/8: sums stay exact, so "on the edge line" is exactly on it.
dyadic = st.integers(-400, 400).map(lambda i: i / 8)
dyadic_half = st.integers(1, 80).map(lambda i: i / 8)


@settings(max_examples=300, deadline=None)
@given(cx=dyadic, cy=dyadic, hl=dyadic_half, hw=dyadic_half,
       along=st.sampled_from([0.0, 0.5, 1.0]), k=st.integers(0, 3), offset=dyadic)
def test_rays_parallel_to_an_edge_are_finite_and_correct(cx, cy, hl, hw, along, k, offset):
    """Rays along the box axes (exactly parallel to two edges), including along an edge line
    (closed box: a ray along an edge hits it)."""
    box = torch.tensor([cx, cy, 0.0, hl, hw], dtype=torch.float64)
    angle = k * math.pi / 2
    direction = [(1, 0), (0, 1), (-1, 0), (0, -1)][k]
    # Origin 25 m behind the box along the ray, shifted sideways by a fraction of the width
    # (along = 1 puts it exactly on an edge line) or by an arbitrary offset.
    side = (hw if k % 2 == 0 else hl) * along if along else offset
    origin = torch.tensor([cx - 25 * direction[0] - side * direction[1],
                           cy - 25 * direction[1] + side * direction[0]], dtype=torch.float64)
    # cos/sin of multiples of pi/2 are not exact in floating point: use exact directions.
    got = ray_box_distance(origin, torch.tensor(angle, dtype=torch.float64), box, 100.0)
    assert torch.isfinite(got)
    exact = shapely_ray(origin.numpy(), angle, box.numpy(), 100.0)
    assert got.item() == pytest.approx(exact, abs=1e-6)


@settings(max_examples=200, deadline=None)
@given(cx=finite, cy=finite, hl=half, hw=half, heading=st.floats(-4, 4),
       fx=st.floats(-0.999, 0.999), fy=st.floats(-0.999, 0.999), angle=st.floats(-7, 7))
def test_origin_inside_a_box_gives_zero(cx, cy, hl, hw, heading, fx, fy, angle):
    box = torch.tensor([cx, cy, heading, hl, hw], dtype=torch.float64)
    c, s = math.cos(heading), math.sin(heading)
    origin = torch.tensor([cx + fx * hl * c - fy * hw * s, cy + fx * hl * s + fy * hw * c],
                          dtype=torch.float64)
    assert ray_box_distance(origin, torch.tensor(angle, dtype=torch.float64), box, 20.0) == 0.0


@settings(max_examples=300, deadline=None)
@given(x=st.integers(-800_000, 800_000).map(lambda i: i / 8), y=st.integers(-8e5, 8e5).map(
       lambda i: i / 8), hl=dyadic_half, hw=dyadic_half, hl2=dyadic_half, hw2=dyadic_half,
       gap=st.sampled_from([-1e-3, 0.0, 1e-3]), right_angle=st.booleans())
def test_axis_aligned_and_right_angle_contacts_at_large_coordinates(x, y, hl, hw, hl2, hw2, gap,
                                                                    right_angle):
    """b sits to the right of a, at distance ``gap`` (0: exactly touching), with b turned by
    90 degrees or not, far from the origin. Touching counts as overlap."""
    a = torch.tensor([x, y, 0.0, hl, hw], dtype=torch.float64)
    b_half_x = hw2 if right_angle else hl2
    heading = math.pi / 2 if right_angle else 0.0
    b = torch.tensor([x + hl + b_half_x + gap, y, heading, hl2, hw2], dtype=torch.float64)
    if gap == 0.0 and not right_angle:
        assert boxes_overlap(a, b)  # exact in floating point: shared edge
    elif gap != 0.0:
        # |gap| = 1 mm: decided well above rounding, even at 1e5 m and with cos(pi/2) != 0.
        assert bool(boxes_overlap(a, b)) == (gap < 0)
        assert bool(boxes_overlap(a, b)) == polygon(a.numpy()).intersects(polygon(b.numpy()))


@given(st.floats(-1e4, 1e4))
def test_wrap_angle_range_and_equivalence(angle):
    wrapped = wrap_angle(torch.tensor(angle, dtype=torch.float64)).item()
    assert -math.pi < wrapped <= math.pi
    assert math.cos(wrapped) == pytest.approx(math.cos(angle), abs=1e-9)
    assert math.sin(wrapped) == pytest.approx(math.sin(angle), abs=1e-9)


def test_broadcasting_shapes():
    a = torch.zeros(3, 1, 5)
    a[..., 3:] = 1.0
    b = torch.zeros(1, 4, 5)
    b[..., 3:] = 1.0
    assert boxes_overlap(a, b).shape == (3, 4)
    assert box_corners(a).shape == (3, 1, 4, 2)
    origins = torch.zeros(3, 1, 2)
    assert ray_box_distance(origins, torch.zeros(1, 4), b[0], 5.0).shape == (3, 4)
