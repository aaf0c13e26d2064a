"""The paper's figures as PNG (matplotlib, no display needed).

Public API (each writes one PNG atomically and returns nothing):
    density_heatmaps(path, raw_xyz, relocated_xyz, axes, cell)     Fig. 6: points per cell, side by side
    notch_width_plot(path, widths_mm, nominal_mm, truth_mm=None)   Fig. 7: scatter by notch and box plot
    side_views(path, raw_xyz, relocated_xyz, mesh, axes)           Fig. 1/5: raw, relocated, mesh
`axes` is a (2, 3) array: the two in-plane directions of the view (e.g. the robot's notch side and its
axis), so every figure looks at the bending plane; `axis_labels` names them. The clouds are framed on the
relocated robot: the raw cloud's points beyond it (the clamp, the table, a backdrop inside the crop box) would
shrink the robot to a few pixels, and the figures count them instead.
"""

from __future__ import annotations

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> None:
    from ntcr_recon.io.files import write_atomically

    write_atomically(path, lambda temp: fig.savefig(temp, dpi=110, format="png"))
    fig.clf()
    _pyplot().close(fig)


def _project(xyz: np.ndarray, axes: np.ndarray) -> np.ndarray:
    return np.asarray(xyz) @ np.asarray(axes).T * 1e3  # mm


def _robot_frame(relocated: np.ndarray, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The figures' frame (mm, low and high corners): the relocated robot with a margin of a tenth of its extent
    and 2 mm; the raw cloud's where nothing was relocated."""
    around = relocated if len(relocated) else raw if len(raw) else np.zeros((1, 2))
    low, high = around.min(axis=0), around.max(axis=0)
    margin = 0.1 * float(np.max(high - low)) + 2.0
    return low - margin, high + margin


def _beyond(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> int:
    return int(np.count_nonzero(np.any((points < low) | (points > high), axis=1)))


def density_heatmaps(path, raw_xyz: np.ndarray, relocated_xyz: np.ndarray, axes: np.ndarray, cell: float,
                     axis_labels: tuple[str, str] = ("mm", "mm")) -> None:
    plt = _pyplot()
    raw, relocated = _project(raw_xyz, axes), _project(relocated_xyz, axes)
    lo, hi = _robot_frame(relocated, raw)
    bins = [np.arange(lo[d], hi[d] + cell * 1e3, cell * 1e3) for d in range(2)]
    fig, panels = plt.subplots(1, 2, figsize=(10, 6), sharex=True, sharey=True)
    counts = [np.histogram2d(p[:, 0], p[:, 1], bins=bins)[0] for p in (relocated, raw)]
    top = max(float(c.max()) for c in counts) or 1.0
    beyond = _beyond(raw, lo, hi)
    titles = ("relocated", "raw fused" + (f" ({beyond} points beyond this frame)" if beyond else ""))
    for panel, count, title in zip(panels, counts, titles, strict=True):
        image = panel.imshow(count.T, origin="lower", extent=(lo[0], hi[0], lo[1], hi[1]), cmap="viridis",
                             vmin=0, vmax=top, aspect="equal")
        panel.set_title(f"{title}: points per {cell * 1e3:.1f} mm cell", fontsize="medium")
        panel.set_xlabel(axis_labels[0])
    panels[0].set_ylabel(axis_labels[1])
    fig.colorbar(image, ax=list(panels), label="points")
    _save(fig, path)


def notch_width_plot(path, widths_mm: list[float], nominal_mm: float, truth_mm: list[float] | None = None,
                     indices: list[int] | None = None) -> None:
    plt = _pyplot()
    fig, (scatter, box) = plt.subplots(1, 2, figsize=(10, 4), gridspec_kw={"width_ratios": [3, 1]})
    index = np.arange(len(widths_mm)) if indices is None else np.asarray(indices)
    scatter.scatter(index, widths_mm, label="measured", zorder=3)
    if truth_mm is not None:
        scatter.scatter(index, truth_mm, marker="x", color="k", label="ground truth", zorder=3)
    scatter.axhline(nominal_mm, color="r", linestyle="--", label=f"nominal {nominal_mm:.2f} mm")
    scatter.set_xlabel("notch (0 = nearest the base)")
    scatter.set_ylabel("width on the notched side (mm)")
    scatter.legend()
    if len(widths_mm):
        box.boxplot(widths_mm)
    box.axhline(nominal_mm, color="r", linestyle="--")
    box.set_xticks([1], ["measured"])
    fig.tight_layout()
    _save(fig, path)


def side_views(path, raw_xyz: np.ndarray, relocated_xyz: np.ndarray, mesh, axes: np.ndarray,
               mesh_title: str = "mesh", axis_labels: tuple[str, str] = ("mm", "mm")) -> None:
    plt = _pyplot()
    fig, panels = plt.subplots(1, 3, figsize=(12, 6), sharex=True, sharey=True)
    raw, relocated = _project(raw_xyz, axes), _project(relocated_xyz, axes)
    lo, hi = _robot_frame(relocated, raw)
    beyond = _beyond(raw, lo, hi)
    raw_title = "raw fused cloud" + (f"\n({beyond} points beyond this frame)" if beyond else "")
    for panel, p, title in ((panels[0], raw, raw_title), (panels[1], relocated, "relocated cloud")):
        panel.scatter(p[:, 0], p[:, 1], s=0.3, color="tab:blue")
        panel.set_title(title)
    if mesh is not None and len(mesh):
        v = _project(mesh.vertices, axes)
        panels[2].triplot(v[:, 0], v[:, 1], mesh.triangles, linewidth=0.1, color="tab:gray")
    panels[2].set_title(mesh_title)
    for panel in panels:
        panel.set_aspect("equal")
        panel.set_xlabel(axis_labels[0])
    panels[0].set_xlim(lo[0], hi[0])  # shared by the three panels
    panels[0].set_ylim(lo[1], hi[1])
    panels[0].set_ylabel(axis_labels[1])
    fig.tight_layout()
    _save(fig, path)


def calibration_views(path, before: dict[str, np.ndarray], after: dict[str, np.ndarray],
                      centerlines: list[np.ndarray], as_points: bool = False) -> None:
    """Both cameras' points (base frame, by camera) over the fitted robots' centrelines, with the rig file's poses
    (top) and the calibrated ones (bottom), seen across the bending plane (x, z) and along it (y, z), framed on the
    robot. as_points: the model is a point set (a target's surface), drawn as dots."""
    plt = _pyplot()
    fig, panels = plt.subplots(2, 2, figsize=(8, 10), width_ratios=(3, 1))
    axes = np.array([[[1.0, 0, 0], [0, 0, 1.0]], [[0, 1.0, 0], [0, 0, 1.0]]])
    for row, (points, label) in enumerate(((before, "rig file's poses"), (after, "calibrated poses"))):
        for column, view in enumerate(axes):
            panel = panels[row, column]
            for name, xyz in points.items():
                p = _project(xyz, view)
                panel.scatter(p[:, 0], p[:, 1], s=0.2, label=name)
            for line in centerlines:
                c = _project(line, view)
                panel.plot(c[:, 0], c[:, 1], "." if as_points else "-", color="black", linewidth=0.8, markersize=0.5)
            panel.set_title(f"{label}, {'x' if column == 0 else 'y'}-z (mm)")
            panel.set_aspect("equal")
            robot = _project(np.concatenate(centerlines), view)
            low, high = robot.min(axis=0) - 4.0, robot.max(axis=0) + 4.0  # the robot and 4 mm round it
            panel.set_xlim(low[0], high[0])
            panel.set_ylim(low[1], high[1])
            panel.locator_params(axis="x", nbins=4 if column == 0 else 3)
    panels[0, 0].legend(markerscale=20)
    fig.tight_layout()
    _save(fig, path)
