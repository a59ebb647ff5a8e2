"""Figures of pose selection: the criterion over the joint 2-3 plane with its regions, the best
criterion over the workspace, and the joints' influence curves (docs/poses.md shows each).

Angles are plotted in degrees (DH convention), positions in metres.
"""

from __future__ import annotations

import numpy as np

from ..lab import PAPER_LAB
from ..plotting import pyplot, save_figure


def plot_joint_plane(pmap, found, path, marks=()) -> None:
    """Contour of the criterion over theta_2 (x) and theta_3 (y) with the regions outlined."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    g2, g3 = np.degrees(pmap.theta2), np.degrees(pmap.theta3)
    cs = ax.contourf(g2, g3, pmap.values.T, levels=np.linspace(0, 1, 21), cmap="viridis")
    fig.colorbar(cs, ax=ax, label=r"$\kappa(J_{AW})^{-1}$")
    for r in found:
        colour = "white" if r.excluded is None else "red"
        if r.removed is not None and r.removed.any():
            whole = (r.mask | r.removed).T.astype(float)
            ax.contour(g2, g3, whole, levels=[0.5], colors="red", linewidths=1.0, linestyles="dashed")
        if r.mask.any():
            ax.contour(g2, g3, r.mask.T.astype(float), levels=[0.5], colors=colour, linewidths=1.2)
        label = r.name if r.excluded is None else f"{r.name} (excluded)"
        cells = r.mask if r.excluded is None or r.removed is None else r.mask | r.removed
        where = np.degrees(r.peak)
        if cells.any():
            i2, i3 = np.nonzero(cells)
            where = (g2[i2].mean(), g3[i3].mean())
        ax.annotate(label, where, color=colour, fontsize=11, ha="center", va="center", weight="bold")
    for name, q, style in marks:
        q = np.atleast_2d(q)
        ax.plot(np.degrees(q[:, 1]), np.degrees(q[:, 2]), style, label=name, ms=8, mec="k", ls="none")
    if marks:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=len(marks), fontsize=8)
    ax.set_xlabel(r"$\theta_2$ (DH) [deg]")
    ax.set_ylabel(r"$\theta_3$ (DH) [deg]")
    q = np.degrees(pmap.q_fixed)
    ax.set_title(
        f"criterion at {pmap.point}; theta1,4,5,6 = {q[0]:.0f}, {q[3]:.0f}, {q[4]:.0f}, {q[5]:.0f} deg"
    )
    save_figure(fig, path, dpi=90)


def plot_cartesian(cmap, path, lab=None) -> None:
    """Best criterion per (x, z) bin of the reference point, with floor and table."""
    plt = pyplot()
    lab = lab or PAPER_LAB
    fig, ax = plt.subplots(figsize=(7.5, 6))
    x = (cmap.x_edges[:-1] + cmap.x_edges[1:]) / 2
    z = (cmap.z_edges[:-1] + cmap.z_edges[1:]) / 2
    values = np.ma.masked_invalid(cmap.values.T)
    cs = ax.contourf(x, z, values, levels=np.linspace(0, 1, 21), cmap="viridis")
    fig.colorbar(cs, ax=ax, label=r"best $\kappa(J_{AW})^{-1}$ reaching the bin")
    t = lab.table
    ax.plot(
        [t.center[0] - t.size[0] / 2, t.center[0] + t.size[0] / 2], [t.height] * 2, "k-", lw=3, label="table"
    )
    ax.axhspan(min(cmap.z_edges[0], 0.0), 0.0, color="0.6", alpha=0.6, label="below the floor")
    ax.plot([0, 0], [0, 0.815], "k--", lw=1, label="axis 1")
    ax.set_aspect("equal")
    ax.set_xlabel("x (base) [m]")
    ax.set_ylabel("z (base) [m]")
    name = "wrist centre" if cmap.point == "wrist" else cmap.point
    ax.set_title(f"{name} position (x, z); theta1 = 0, theta6 = 45 deg")
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, path, dpi=90)


def plot_influence(inf, path) -> None:
    """Curves along each joint (paper Fig. 3) and shifted to a common maximum (Fig. 4)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for c in inf.curves:
        label = f"joint {c.joint}: {c.curvature(inf.method):.3g} /deg$^2$"
        axes[0].plot(np.degrees(c.angles), c.values, label=label)
        axes[1].plot(np.degrees(c.angles - c.at), c.values, label=f"joint {c.joint}")
    axes[0].set_xlabel("joint angle (DH) [deg]")
    axes[1].set_xlabel("joint angle - optimum [deg]")
    axes[1].set_xlim(-90, 90)
    for ax in axes:
        ax.set_ylabel(r"$\kappa(J_{AW})^{-1}$")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title(f"influence at {inf.point}; ranking {' > '.join(map(str, inf.ranking))}")
    save_figure(fig, path, dpi=90)
