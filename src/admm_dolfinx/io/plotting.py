"""Figures: deformed body coloured by von Mises stress, contact pressure, iterations vs r.

pyvista draws the meshes off-screen (``PYVISTA_OFF_SCREEN=true``) and matplotlib the
curves. Distributed data are gathered to rank 0, which alone writes the PNG files
(through a temporary file, so a figure is written whole or not at all). Nothing here
is needed to solve a problem: the solver never imports this module.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from dolfinx import fem, plot
from mpi4py import MPI

from admm_dolfinx._mpi import gather_concat, gather_objects
from admm_dolfinx.io.output import atomic_path, rank0_write
from admm_dolfinx.scenes.material import LinearElastic


def _prefer_egl() -> None:
    """Render off-screen through EGL when there is no X display and EGL exists.

    VTK's default X window would otherwise first fail to reach an X server (warning
    "bad X server connection") and then fall back. A user's own choice of
    ``VTK_DEFAULT_OPENGL_WINDOW`` is kept.
    """
    if os.environ.get("DISPLAY") or "VTK_DEFAULT_OPENGL_WINDOW" in os.environ:
        return
    import ctypes.util

    if ctypes.util.find_library("EGL"):
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = "vtkEGLRenderWindow"


_prefer_egl()

__all__ = [
    "obstacle_surface",
    "plot_contact_pressure",
    "plot_deformed_von_mises",
    "plot_iterations_vs_penalty",
]


def _atomic_png(path: Path, save) -> None:
    with atomic_path(path) as tmp:
        save(str(tmp))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _ticker():
    from matplotlib import ticker

    return ticker


def von_mises_cells(u: fem.Function, material: LinearElastic) -> fem.Function:
    """Von Mises stress of u as a cell-wise constant (DG0) Function."""
    msh = u.function_space.mesh
    W = fem.functionspace(msh, ("DG", 0))
    vm = fem.Function(W, name="von_mises")
    vm.interpolate(fem.Expression(material.von_mises(u), W.element.interpolation_points))
    return vm


def _gathered_grid(u: fem.Function, cell_values: fem.Function):
    """(points, cells, types, u, values) of the whole mesh on rank 0 (None elsewhere)."""
    import pyvista

    V = u.function_space
    comm = V.mesh.comm
    # dolfinx registers vtk_mesh's FunctionSpace variant with functools.singledispatch;
    # mypy sees only the Mesh one
    topology, cell_types, points = plot.vtk_mesh(V)  # type: ignore[arg-type]
    bs = V.dofmap.index_map_bs
    n_points = points.shape[0]
    values_u = u.x.array.reshape(-1, bs)[:n_points]
    if bs == 2:
        values_u = np.hstack([values_u, np.zeros((n_points, 1))])
    n_cells = cell_types.size
    cell_dofs = cell_values.function_space.dofmap.list[:n_cells, 0]
    cvals = cell_values.x.array[cell_dofs]
    parts = gather_objects(comm, (topology, cell_types, points, values_u, cvals))
    if parts is None:
        return None
    grids = []
    for topo, types, pts, uu, cv in parts:
        grid = pyvista.UnstructuredGrid(topo, types, pts)
        grid.point_data["u"] = uu
        grid.cell_data["von Mises"] = cv
        grids.append(grid)
    merged = grids[0] if len(grids) == 1 else grids[0].merge(grids[1:])
    return merged


def plot_deformed_von_mises(
    u: fem.Function,
    material: LinearElastic,
    path: str | os.PathLike,
    *,
    title: str = "",
    scale: float | None = None,
    obstacle_mesh=None,
    obstacle_shift: np.ndarray | None = None,
) -> float:
    """Draw the deformed body coloured by von Mises stress (paper Figs. 6 and 9); collective.

    Args:
        u: Displacement.
        material: Material (for the stress).
        path: PNG file (written by rank 0).
        title: Figure title.
        scale: Displacement magnification; by default the largest displacement is
            drawn as 5 % of the body's diameter (never shrunk below 1).
        obstacle_mesh: Optional pyvista mesh of the obstacle to draw beside the body
            (see :func:`obstacle_surface`).
        obstacle_shift: The displacement of the body where it touches (e.g. the mean
            displacement of the active contact nodes). The obstacle is drawn moved by
            (magnification − 1) times it, so that the magnified body touches it where
            the real one does, instead of seeming to sink into it.

    Returns:
        The magnification used.
    """
    vm = von_mises_cells(u, material)
    grid = _gathered_grid(u, vm)
    comm = u.function_space.mesh.comm

    def draw() -> float:
        import pyvista

        magnification = scale

        size = float(np.linalg.norm(np.ptp(grid.points, axis=0)))
        umax = float(np.max(np.linalg.norm(grid.point_data["u"], axis=1)))
        if magnification is None:
            magnification = max(1.0, 0.05 * size / umax) if umax > 0 else 1.0
        warped = grid.warp_by_vector("u", factor=magnification)
        plotter = pyvista.Plotter(off_screen=True, window_size=[1200, 800])
        plotter.add_mesh(grid, style="wireframe", color="grey", opacity=0.25)
        plotter.add_mesh(
            warped,
            scalars="von Mises",
            cmap="viridis",
            show_edges=True,
            edge_color="black",
            line_width=0.3,
            # vertical, at the right edge, labels to 3 significant digits: the default
            # horizontal bar ran its last label off the picture and over the obstacle
            scalar_bar_args={
                "title": "von Mises stress",
                "vertical": True,
                "position_x": 0.86,
                "position_y": 0.15,
                "height": 0.7,
                "width": 0.06,
                "fmt": "%.3g",
                "title_font_size": 16,
                "label_font_size": 14,
            },
        )
        if obstacle_mesh is not None:
            drawn = obstacle_mesh
            if obstacle_shift is not None:
                shift = np.zeros(3)
                shift[: len(obstacle_shift)] = (magnification - 1.0) * np.asarray(obstacle_shift)
                drawn = obstacle_mesh.translate(shift, inplace=False)
            plotter.add_mesh(drawn, color="saddlebrown", opacity=0.3, line_width=3)
        plotter.add_text(f"{title}  (displacement x{magnification:.3g})", font_size=11)
        if np.allclose(grid.points[:, 2], 0.0):
            # Plotter.view_xy and .show_axes forward to the active renderer; called there
            # because their functools.wraps signatures hide their `self` from mypy
            plotter.renderer.view_xy()
        else:  # from below, so that the contact face is in view
            center = np.asarray(grid.center)
            plotter.camera_position = [
                tuple(center + size * np.array([1.2, -1.5, -1.0])),
                tuple(center),
                (0, 0, 1),
            ]
        plotter.renderer.show_axes()
        try:
            _atomic_png(Path(path), lambda tmp: plotter.screenshot(tmp))
        finally:
            plotter.close()
        return magnification

    return float(rank0_write(comm, Path(path), draw))


def _gather_contact(problem, values):
    gathered = gather_concat(problem.comm, problem.contact.coordinates, np.asarray(values))
    return (None, None) if gathered is None else gathered


def plot_contact_pressure(
    problem,
    pressures: Sequence[tuple[str, np.ndarray]],
    path: str | os.PathLike,
    *,
    title: str = "",
    coordinate: str = "x",
) -> None:
    """Normal stress σ_n = −λ along Γ_C (paper Figs. 3, 7 and 10); collective.

    In 2D: σ_n against x (``coordinate="x"``) or against the polar angle about the
    obstacle-free centre (``"angle"``, for the Hertz arc). In 3D: a filled contour
    plot over the contact face (x, y).

    Args:
        problem: The contact problem.
        pressures: Labelled multiplier arrays (owned contact nodes), e.g. several meshes
            or solvers of the same problem; in 3D only the first is drawn.
        path: PNG file.
        title: Figure title.
        coordinate: Abscissa in 2D.
    """
    gathered = [(label, *_gather_contact(problem, lam)) for label, lam in pressures]
    rank0_write(
        problem.comm,
        Path(path),
        lambda: _draw_contact_pressure(gathered, problem.gdim, path, title, coordinate),
    )


def _draw_contact_pressure(gathered, gdim, path, title, coordinate) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if gdim == 2:
        for label, xc, lam in gathered:
            if coordinate == "angle":
                centre = np.array([0.0, np.max(xc[:, 1])])
                s = np.degrees(np.arctan2(xc[:, 0] - centre[0], centre[1] - xc[:, 1]))
                ax.set_xlabel("angle from the lowest point [deg]")
            else:
                s = xc[:, 0]
                ax.set_xlabel("x")
            order = np.argsort(s)
            ax.plot(s[order], -lam[order], marker="o", markersize=2.5, label=label)
        ax.set_ylabel("normal stress σ_n = −λ on Γ_C")
        ax.grid(True, alpha=0.3)
        if len(gathered) > 1:
            ax.legend()
    else:
        label, xc, lam = gathered[0]
        low = min(float(np.min(-lam)), -1e-300)
        levels = np.linspace(low, 0.0, 21)
        levels[-1] = abs(low) * 1e-9  # include σ_n = 0 (no contact) in the top level
        contour = ax.tricontourf(xc[:, 0], xc[:, 1], -lam, levels=levels, cmap="viridis_r")
        bar = fig.colorbar(contour, ax=ax, label="normal stress σ_n = −λ")
        # round ticks in scientific notation, not the 21 contour levels' raw values
        ticks = _ticker().MaxNLocator(nbins=6).tick_values(low, 0.0)
        bar.set_ticks(ticks[(ticks >= low) & (ticks <= 0.0)])
        bar.formatter = _ticker().FuncFormatter(lambda value, _: f"{value:.3g}")
        bar.update_ticks()
        ax.set_aspect("equal")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    ax.set_title(title)
    fig.tight_layout()
    try:
        _atomic_png(Path(path), lambda tmp: fig.savefig(tmp, dpi=130))
    finally:
        plt.close(fig)


def plot_iterations_vs_penalty(
    curves: Sequence[tuple[str, np.ndarray, np.ndarray]],
    path: str | os.PathLike,
    *,
    title: str = "",
    marks: Sequence[tuple[str, float, float]] = (),
    comm: MPI.Comm = MPI.COMM_WORLD,
) -> None:
    """Iterations against r (paper Figs. 2 and 5); rank 0 draws; collective over ``comm``.

    Args:
        curves: ``(label, r, iterations)`` per mesh.
        path: PNG file.
        title: Figure title.
        marks: ``(label, r, iterations)`` points to mark, e.g. r* and r̄.
        comm: Communicator (rank 0 draws; a failure there is raised on every rank).
    """
    rank0_write(comm, Path(path), lambda: _draw_iterations(curves, path, title, marks))


def _draw_iterations(curves, path, title, marks) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label, r, its in curves:
        ax.plot(r, its, label=label, linewidth=1.2)
    for label, r, its in marks:
        ax.plot([r], [its], marker="*", markersize=11, linestyle="none", label=label)
    ax.set_xscale("log")
    ax.set_xlabel("penalty r (log scale)")
    ax.set_ylabel("ADMM iterations")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        _atomic_png(Path(path), lambda tmp: fig.savefig(tmp, dpi=130))
    finally:
        plt.close(fig)


def obstacle_surface(obstacle, bounds: np.ndarray):
    """A pyvista mesh of a Plane or Ball near the body, for drawing (None otherwise).

    Args:
        obstacle: The obstacle.
        bounds: (2, 3) array of the body's lower and upper corners.

    Returns:
        A pyvista mesh, or None for obstacles it cannot draw.
    """
    import pyvista

    from admm_dolfinx.problem.obstacles import Ball, Plane

    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    size = float(np.linalg.norm(hi - lo))
    if isinstance(obstacle, Ball):
        c = np.zeros(3)
        c[: obstacle.center.size] = obstacle.center
        if obstacle.center.size == 2:
            return pyvista.Circle(radius=obstacle.radius, resolution=200).translate(c)
        return pyvista.Sphere(
            radius=obstacle.radius, center=c, theta_resolution=60, phi_resolution=30
        )
    if isinstance(obstacle, Plane):
        p = np.zeros(3)
        n = np.zeros(3)
        p[: obstacle.point.size] = obstacle.point
        n[: obstacle.normal.size] = obstacle.normal
        centre = 0.5 * (lo + hi)
        foot = centre - ((centre - p) @ n) * n
        if obstacle.point.size == 2:
            t = np.array([-n[1], n[0], 0.0])
            return pyvista.Line(foot - 0.6 * size * t, foot + 0.6 * size * t)
        return pyvista.Plane(center=foot, direction=n, i_size=size, j_size=size)
    return None
