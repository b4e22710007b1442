import numpy as np
import pytest

from admm_dolfinx import Ball, Plane


def test_plane_gap_along_normal():
    plane = Plane(point=(0.0, -0.01), normal=(0.0, 2.0))  # normal is normalised
    x = np.array([[0.3, 0.0], [1.0, 0.5], [0.0, -0.02]])
    n = np.array([[0.0, -1.0], [np.sqrt(0.5), -np.sqrt(0.5)], [0.0, -1.0]])
    g = plane.gap(x, n)
    # straight down: 0.01; at 45 degrees from height 0.51: 0.51 * sqrt(2); below: -0.01
    np.testing.assert_allclose(g, [0.01, 0.51 * np.sqrt(2), -0.01], rtol=1e-14)


def test_plane_gap_infinite_when_moving_away():
    plane = Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    g = plane.gap(np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    assert g[0] == np.inf


def test_ball_gap_hits_misses_and_penetrates():
    ball = Ball(center=(0.0, 0.0, -1.0), radius=0.5)
    x = np.array([[0.0, 0.0, -0.3], [0.3, 0.0, -0.5], [2.0, 0.0, 0.0], [0.0, 0.0, -0.6]])
    n = np.tile([0.0, 0.0, -1.0], (4, 1))
    g = ball.gap(x, n)
    assert g[0] == pytest.approx(0.2, rel=1e-14)
    assert g[1] == pytest.approx(0.1, rel=1e-12)  # ball surface at x=0.3 is z=-0.6
    assert g[2] == np.inf  # the ray misses the ball
    assert g[3] == pytest.approx(-0.1, rel=1e-12)  # inside: back out by 0.1


def test_ball_gap_negative_inside():
    disc = Ball(center=(0.0, 0.0), radius=1.0)
    g = disc.gap(np.array([[0.0, 0.9]]), np.array([[0.0, -1.0]]))
    assert g[0] == pytest.approx(-0.1, rel=1e-12)


@pytest.mark.parametrize("normal", [(0.0, 0.0), (0.0, 0.0, 0.0)])
def test_plane_zero_normal_is_rejected(normal):
    with pytest.raises(ValueError, match="zero length"):
        Plane(point=(0.0,) * len(normal), normal=normal)


@pytest.mark.parametrize("radius", [0.0, -1.0, np.nan, np.inf])
def test_ball_bad_radius(radius):
    with pytest.raises(ValueError, match="radius"):
        Ball((0.0, 0.0), radius)
