"""Analytic rigid obstacles: the signed distance and normal, or the gap along a ray.

Two models of the linearised non-penetration condition at contact node j
(:class:`~admm_dolfinx.ContactProblem`'s ``contact_normal``):

* ``"obstacle"`` (default): along the **obstacle's** unit normal ν_j at the point of
  the obstacle closest to x_j, with g_j the signed distance:
  −u_j · ν_j ≤ g_j. This is what a rigid-master contact code imposes, and it keeps a
  curved body out of a plane however wide the contact zone.
* ``"body"`` (the paper's): along the body's outward nodal normal n_j, with g_j the
  distance from x_j to the obstacle along the ray x_j + t n_j: u_j · n_j ≤ g_j. Exact
  only where the body's surface is parallel to the obstacle.

An obstacle implements :meth:`Obstacle.signed_distance` for the first and
:meth:`Obstacle.gap` for the second; :class:`Plane` and :class:`Ball` implement both,
exactly. Sign conventions: a positive gap is room to move, a negative one an initial
penetration, +inf a node that can never touch. The inputs of both methods are
read-only arrays; they must return new arrays.
"""

from __future__ import annotations

import abc

import numpy as np
import numpy.typing as npt

__all__ = ["Ball", "Obstacle", "Plane", "implements", "obstacle_state"]


class Obstacle(abc.ABC):  # noqa: B024 - an interface of two optional methods
    """A rigid obstacle described analytically.

    Implement :meth:`signed_distance` (the default model, along the obstacle's
    normal), :meth:`gap` (the paper's model, along the body's normal), or both.
    Everything else (nodal normals, contact nodes, parallel layout) is done by
    :class:`admm_dolfinx.ContactProblem`.

    A user who can only give the distance along a ray (the gap of the paper's model)
    implements :meth:`gap` alone and builds the problem with ``contact_normal="body"``.
    """

    def signed_distance(
        self, x: npt.NDArray[np.floating]
    ) -> tuple[npt.NDArray[np.floating], npt.NDArray[np.floating]]:
        """The signed distance of points to the obstacle, and its normal there.

        Args:
            x: Node coordinates, shape ``(k, gdim)``, read-only.

        Returns:
            ``(g, nu)``: g of shape ``(k,)``, the distance from each point to the
            closest point of the obstacle's surface, positive outside the obstacle,
            negative inside (initial penetration), ``+inf`` where the point can never
            touch it; nu of shape ``(k, gdim)``, the obstacle's outward unit normal at
            that closest point (from the obstacle towards the point; ignored where g
            is +inf).
        """
        raise NotImplementedError

    def gap(self, x: npt.NDArray[np.floating], n: npt.NDArray[np.floating]) -> npt.NDArray:
        """The gap of points along directions (the paper's model).

        Args:
            x: Node coordinates, shape ``(k, gdim)``, read-only.
            n: Outward unit normals of the body at those nodes, shape ``(k, gdim)``,
                read-only.

        Returns:
            Array of shape ``(k,)``: the signed distance along ``n`` from each point to
            the obstacle surface; negative for a penetrating point, ``+inf`` where the
            ray never meets the obstacle.
        """
        raise NotImplementedError

    def check_dimension(self, gdim: int) -> None:  # noqa: B027 - optional hook
        """Raise if the obstacle cannot be used in ``gdim`` dimensions (default: no check).

        Args:
            gdim: Geometric dimension of the mesh.
        """


def implements(obstacle: Obstacle, method: str) -> bool:
    """Whether ``obstacle``'s class overrides :class:`Obstacle`'s ``method``."""
    return getattr(type(obstacle), method) is not getattr(Obstacle, method)


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

    def signed_distance(self, x):  # noqa: D102
        x = np.asarray(x, dtype=np.float64)
        height = (x - self.point) @ self.normal  # > 0 on the body's side
        return height, np.tile(self.normal, (x.shape[0], 1))

    def gap(self, x, n):
        """The distance along ``n`` to the plane (see :meth:`Obstacle.gap`).

        A point above the plane whose ray points away never meets it: +inf. A point
        below the plane (inside the obstacle) whose normal points away from the plane
        cannot be pushed out along its normal at all: −inf, which the problem refuses
        with an explanation (the default ``contact_normal="obstacle"`` handles it).
        """
        x = np.asarray(x, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        height = (x - self.point) @ self.normal  # > 0 above the plane
        approach = -(n @ self.normal)  # > 0 when moving along n goes towards the plane
        with np.errstate(divide="ignore", invalid="ignore"):
            along = height / np.where(approach > 0, approach, 1.0)
        return np.where(approach > 0.0, along, np.where(height < 0.0, -np.inf, np.inf))

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

    def signed_distance(self, x):  # noqa: D102
        x = np.asarray(x, dtype=np.float64)
        d = x - self.center
        length = np.linalg.norm(d, axis=1)
        up = np.zeros(x.shape[1])
        up[-1] = 1.0  # the centre itself: any direction is closest; take "up"
        with np.errstate(invalid="ignore", divide="ignore"):
            nu = np.where(length[:, None] > 0.0, d / length[:, None], up)
        return length - self.radius, nu

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
