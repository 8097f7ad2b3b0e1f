"""Figures of the simulation study (thesis Figs. 5.2-5.4 analogues) and the stability analysis."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..report.figures import save, subplots
from .stability import Analysis
from .study import euler_angles

STYLE = {"nominal": ("tab:red", "-"), "compensated": ("tab:blue", "-"), "oracle": ("tab:green", "--")}


def tracking_figure(runs: dict, path, title: str) -> None:
    """Figs. 5.2/5.3: desired vs flown path (3D) and per axis, for the controllers in ``runs``.

    ``runs`` maps a label ('nominal', 'compensated: x', 'oracle') to a flight log.
    """
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(11, 5.5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    first = next(iter(runs.values()))
    ax3.plot(first["ref_px"], first["ref_py"], first["ref_pz"], "k:", lw=1.5, label="desired")
    for label, log in runs.items():
        c, ls = STYLE[label.split(":")[0]]
        ax3.plot(log["px"], log["py"], log["pz"], color=c, ls=ls, lw=1, label=label)
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax3.legend(fontsize=7, loc="upper left")
    first_ax = None
    for i, ax_name in enumerate("xyz"):
        ax = fig.add_subplot(3, 2, 2 * i + 2, sharex=first_ax)  # one time axis, labelled at the bottom
        first_ax = first_ax or ax
        if i < 2:
            ax.tick_params(labelbottom=False)
        for label, log in runs.items():
            c, ls = STYLE[label.split(":")[0]]
            ax.plot(log["t"], 1000 * (log[f"p{ax_name}"] - log[f"ref_p{ax_name}"]), color=c, ls=ls, lw=1,
                    label=label)
        ax.set_ylabel(f"{ax_name} error (mm)")
        if i == 2:
            ax.set_xlabel("t (s)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save(fig, path)


def euler_figure(log, path, title: str) -> None:
    """Fig. 5.4: roll, pitch, yaw against their desired values."""
    act, des = euler_angles(log)
    fig, axes = subplots(3, 1, figsize=(8, 6), sharex=True)
    for i, name in enumerate(["roll", "pitch", "yaw"]):
        axes[i].plot(log["t"], np.degrees(des[:, i]), "k:", lw=1.5, label="desired")
        axes[i].plot(log["t"], np.degrees(act[:, i]), color="tab:blue", lw=1, label="actual")
        axes[i].set_ylabel(f"{name} (deg)")
    axes[0].legend(fontsize=7)
    axes[2].set_xlabel("t (s)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save(fig, path)


def rmse_figure(table, path) -> None:
    """Position RMSE of every source and controller (log scale), diverged runs hatched."""
    fig, ax = subplots(figsize=(max(6, 0.55 * len(table)), 4))
    labels = [f"{s}\n{c}" for s, c in zip(table["source"], table["controller"])]
    colors = [STYLE[c.split(":")[0]][0] for c in table["controller"]]
    bars = ax.bar(range(len(table)), 1000 * table["rmse"], color=colors)
    for b, st in zip(bars, table["status"]):
        if st != "ok":
            b.set_hatch("//")
    ax.set_yscale("log")
    ax.set_xticks(range(len(table)), labels, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("position RMSE (mm)")
    fig.tight_layout()
    save(fig, path)


def eigenvalue_figure(analyses: Mapping[str, Analysis], path) -> None:
    """Eigenvalues of M_{v,a} (eq. 5.15) per model against the unit circle."""
    fig, ax = subplots(figsize=(5.5, 5))
    th = np.linspace(0, 2 * np.pi, 400)
    ax.plot(np.cos(th), np.sin(th), "k-", lw=0.8, label="|λ| = 1")
    markers = "osd^v<>p*h"
    for i, (name, an) in enumerate(analyses.items()):
        lam = an.eigenvalues
        ax.scatter(lam.real, lam.imag, marker=markers[i % len(markers)], s=40, alpha=0.8, label=name)
    ax.set_aspect("equal")
    ax.set_xlabel("Re λ (dimensionless)")
    ax.set_ylabel("Im λ (dimensionless)")
    ax.legend(fontsize=7)
    ax.set_title("eig(M_{v,a}) at hover (eq. 5.15)", fontsize=10)
    save(fig, path)


def divergence_figure(runs: dict, path, limit_g: float | None = None) -> None:
    """Acceleration and position error of the closed loops with a_b-input models in the plant (log-log)."""
    fig, axes = subplots(2, 1, figsize=(8, 6), sharex=True)
    for i, (label, log) in enumerate(runs.items()):
        t = log["t"].to_numpy()
        keep = t > 0
        acc = np.linalg.norm(log[["ax", "ay", "az"]].to_numpy(), axis=1) / 9.81
        e = np.linalg.norm(log[["px", "py", "pz"]].to_numpy() - log[["ref_px", "ref_py", "ref_pz"]].to_numpy(),
                           axis=1)
        ls = "--" if "implicit" in label else "-"
        c = f"C{i // 2}"
        axes[0].plot(t[keep], acc[keep], lw=1, ls=ls, color=c, label=label)
        axes[1].plot(t[keep], np.maximum(e[keep], 1e-7), lw=1, ls=ls, color=c)
    if limit_g:
        axes[0].axhline(limit_g, color="k", lw=0.8, ls=":", label="divergence limit")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("|acceleration| (g)")
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].set_yscale("log")
    axes[1].set_xscale("log")
    axes[1].set_ylabel("position error (m)")
    axes[1].set_xlabel("t (s)")
    fig.suptitle("closed loop with the a_b-input model in the plant: lagged (thesis eq. 5.13) vs implicit", fontsize=10)
    fig.tight_layout()
    save(fig, path)
