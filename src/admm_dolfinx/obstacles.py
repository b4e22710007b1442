"""Analytic rigid obstacles and the normalised gap.

The gap of contact node j is the distance g_j ≥ 0 the node may travel along its
outward unit normal n_j before it meets the obstacle, so the constraint reads
u_j · n_j ≤ g_j.  A node that already penetrates the obstacle has g_j < 0; a node
whose normal ray never meets the obstacle has g_j = +inf (it can never touch).

A user-defined obstacle is a small subclass of :class:`Obstacle` implementing
:meth:`Obstacle.gap`.
"""

from __future__ import annotations

import abc

import numpy as np
import numpy.typing as npt

__all__ = ["Ball", "Obstacle", "Plane", "obstacle_state"]


class Obstacle(abc.ABC):
    """A rigid obstacle described analytically.

    Subclasses implement :meth:`gap`; everything else (nodal normals, contact nodes,
    parallel layout) is done by :class:`admm_dolfinx.ContactProblem`.
    """

    @abc.abstractmethod
    def gap(self, x: npt.NDArray[np.floating], n: npt.NDArray[np.floating]) -> npt.NDArray:
        """Return the normalised gap of points ``x`` along directions ``n``.

        Args:
            x: Node coordinates, shape ``(k, gdim)``.
            n: Outward unit normals of the body at those nodes, shape ``(k, gdim)``.

        Returns:
            Array of shape ``(k,)``: the signed distance along ``n`` from each point to
            the obstacle surface; negative for a penetrating point, ``+inf`` where the
            ray never meets the obstacle.
        """

    def check_dimension(self, gdim: int) -> None:  # noqa: B027 - optional hook
        """Raise if the obstacle cannot be used in ``gdim`` dimensions (default: no check).

        Args:
            gdim: Geometric dimension of the mesh.
        """


def _as_vector(value: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.size not in (2, 3):
        raise ValueError(f"{name} must have 2 or 3 components, got {arr.size}.")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}.")
    return arr


class Plane(Obstacle):
    """A rigid half-space bounded by a plane (a line in 2D).

    Args:
        point: Any point of the plane.
        normal: Normal of the plane, pointing *from the obstacle towards the body*
            (e.g. ``(0, 1)`` for a floor under the body). It need not be unit length.

    Raises:
        ValueError: If ``normal`` has zero length or point and normal differ in size.
    """

    def __init__(self, point: npt.ArrayLike, normal: npt.ArrayLike):
        self.point = _as_vector(point, "Plane point")
        normal = _as_vector(normal, "Plane normal")
        if self.point.size != normal.size:
            raise ValueError(
                f"Plane point has {self.point.size} components but normal has {normal.size}; "
                "give both in the mesh's geometric dimension."
            )
        length = np.linalg.norm(normal)
        if not length > 0.0:
            raise ValueError(
                "Plane normal has zero length; give a non-zero vector pointing from the "
                "obstacle towards the body, e.g. Plane(point, normal=(0, 1))."
            )
        self.normal = normal / length

    def check_dimension(self, gdim: int) -> None:  # noqa: D102
        if self.point.size != gdim:
            raise ValueError(
                f"Plane is defined in {self.point.size}D but the mesh is {gdim}D; "
                f"give point and normal with {gdim} components."
            )

    def gap(self, x, n):  # noqa: D102
        x = np.asarray(x, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        height = (x - self.point) @ self.normal  # > 0 above the plane
        approach = -(n @ self.normal)  # > 0 when moving along n goes towards the plane
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(approach > 0.0, height / np.where(approach > 0, approach, 1.0), np.inf)
        return g

    def __repr__(self) -> str:
        return f"Plane(point={self.point.tolist()}, normal={self.normal.tolist()})"


class Ball(Obstacle):
    """A rigid ball in 3D, or a rigid disc in 2D.

    Args:
        center: Centre of the ball.
        radius: Its radius, > 0.

    Raises:
        ValueError: If the radius is not a positive finite number.
    """

    def __init__(self, center: npt.ArrayLike, radius: float):
        self.center = _as_vector(center, "Ball center")
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0.0):
            raise ValueError(f"Ball radius must be a positive finite number, got {radius}.")
        self.radius = radius

    def check_dimension(self, gdim: int) -> None:  # noqa: D102
        if self.center.size != gdim:
            raise ValueError(
                f"Ball is defined in {self.center.size}D but the mesh is {gdim}D; "
                f"give a center with {gdim} components."
            )

    def gap(self, x, n):  # noqa: D102
        x = np.asarray(x, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        d = x - self.center
        # |d + t n|^2 = R^2  <=>  t^2 + 2 b t + c = 0  (n is a unit vector)
        b = np.einsum("ij,ij->i", d, n)
        c = np.einsum("ij,ij->i", d, d) - self.radius**2
        disc = b * b - c
        g = np.full(x.shape[0], np.inf)
        hit = disc >= 0.0
        first = -b[hit] - np.sqrt(disc[hit])  # entry point along the ray
        # Outside the ball (c >= 0) the gap is the entry distance if it lies ahead.
        # Inside (c < 0) the first root is negative: the distance back to the surface.
        outside = c[hit] >= 0.0
        ahead = first >= 0.0
        gh = np.where(outside & ~ahead, np.inf, first)
        g[hit] = gh
        return g

    def __repr__(self) -> str:
        return f"Ball(center={self.center.tolist()}, radius={self.radius})"


def obstacle_state(obstacle: Obstacle) -> tuple:
    """A snapshot of an obstacle's data, to detect a change made in place.

    Arrays are compared by value, numbers, strings and containers by their repr, other
    attributes by identity.
    """
    items: list[tuple] = []
    for name, value in sorted(vars(obstacle).items()):
        if isinstance(value, np.ndarray):
            items.append((name, value.dtype.str, value.shape, value.tobytes()))
        elif isinstance(value, int | float | complex | str | bool | tuple | list | dict):
            items.append((name, repr(value)))
        else:
            items.append((name, id(value)))
    return tuple(items)
