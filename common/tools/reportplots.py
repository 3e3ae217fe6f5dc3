"""The figures of ``bipedtele report --plots``: delay (Fig. 9), coordination (Fig. 11), tracking (Fig. 12).

Drawn from the signals :func:`bipedtele.tools.reportdata.collect` reads; matplotlib (the
``plots`` extra) is imported only when a figure is drawn.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from bipedtele.recording.format import Record
from bipedtele.tools.reportdata import Run, collect, delay_source, task_window

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["fictitious_intervals", "plot_report"]


def fictitious_intervals(t: np.ndarray, f_t: np.ndarray, threshold: float = 1e-6) -> list[tuple[float, float]]:
    """Time intervals [s] where the tangential fictitious force acts (``|f_t| > threshold``).

    An interval runs from its first active sample to the first inactive one after it (to
    the last sample if it lasts to the end).
    """
    t = np.asarray(t, dtype=float)
    on = np.abs(np.asarray(f_t, dtype=float)) > threshold
    out: list[tuple[float, float]] = []
    start: float | None = None
    for ti, o in zip(t, on, strict=True):
        if o and start is None:
            start = float(ti)
        elif not o and start is not None:
            out.append((start, float(ti)))
            start = None
    if start is not None:
        out.append((start, float(t[-1])))
    return out


def _rel(t: Sequence[float], t0: float) -> np.ndarray:
    return np.asarray(t, dtype=float) - t0


def plot_report(records: Iterable[Record]) -> dict[str, Figure]:
    """Figures like the paper's: ``fig9_delay``, ``fig11_coordination``, ``fig12_tracking``.

    Parameters
    ----------
    records : iterable of Record
        A recording (read once).

    Returns
    -------
    dict of str to matplotlib Figure
        Time axes in seconds from the task start; the task window is shaded.
        ``fig9_delay``: h1, h2 and h1 + h2 [ms]. ``fig11_coordination``: (a) commanded
        (sent) vs robot forward speed and the equivalent speed z_e the operator feels
        [cm/s], (b) the same for the turn speed [deg/s], (c) the fictitious force f_v
        (tangential, normal; from the feedback, else the leader's state samples), (d) the
        handle force f_m [N] (when recorded); the intervals where the tangential f_v acts
        (:func:`fictitious_intervals`) are shaded on every panel. ``fig12_tracking``: (a) the reference
        applied on the robot vs its forward speed [cm/s], (b) the turn angle commanded
        (integral of the applied turn-speed reference) vs the robot's yaw [deg].
    """
    run = collect(records)
    window = task_window(run) or (0.0, 0.0)
    t0 = window[0]
    from matplotlib.figure import Figure  # the ``plots`` extra: only the figures need it

    def shade(ax: Any) -> None:
        ax.axvspan(0.0, window[1] - t0, color="0.9", zorder=0)
        ax.grid(True, alpha=0.3)

    return {
        "fig9_delay": _fig9_delay(Figure, run, t0, shade),
        "fig11_coordination": _fig11_coordination(Figure, run, t0, shade),
        "fig12_tracking": _fig12_tracking(Figure, run, t0, shade),
    }


def _fig9_delay(figure: type[Figure], run: Run, t0: float, shade: Callable[[Any], None]) -> Figure:
    """Fig. 9: total delay."""
    fig = figure(figsize=(8, 3.2), layout="constrained")
    ax = fig.add_subplot()
    t, d = delay_source(run)
    if d:
        da = 1000.0 * np.asarray(d)
        tr = _rel(t, t0)
        ax.plot(tr, da.sum(axis=1), color="C3", label="h1 + h2")
        ax.plot(tr, da[:, 0], color="C0", lw=0.8, ls="--", label="h1 (forward)")
        ax.plot(tr, da[:, 1], color="C1", lw=0.8, ls="--", label="h2 (backward)")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("delay [ms]")
    ax.set_title("Total delay h1 + h2 (1 s moving average)")
    shade(ax)
    return fig


def _fig11_coordination(figure: type[Figure], run: Run, t0: float, shade: Callable[[Any], None]) -> Figure:
    """Fig. 11: commanded vs robot speeds, the fictitious force and the handle force.

    The intervals where f_v acts are shaded (the paper's rectangles).
    """
    fig = figure(figsize=(8, 9), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    cmd = np.asarray(run.cmd_ref, dtype=float).reshape(-1, 2)
    eta = np.asarray(run.fb_eta, dtype=float).reshape(-1, 2)
    ze = np.asarray(run.ze, dtype=float).reshape(-1, 2)
    fv_t, fv = (run.fv_t, run.fv) if run.fv else (run.state_fv_t, run.state_fv)
    fva = np.asarray(fv, dtype=float).reshape(-1, 2)
    acts = fictitious_intervals(_rel(fv_t, t0), fva[:, 0]) if len(fva) else []

    def shade_fv(ax: Any) -> None:
        for i, (a0, a1) in enumerate(acts):
            ax.axvspan(a0, a1, color="tab:orange", alpha=0.18, zorder=0, label="f_v acts" if i == 0 else None)

    for i, (unit, name) in enumerate((("cm/s", "forward speed"), ("deg/s", "turn speed"))):
        a = axes[i]
        if len(cmd):
            a.plot(_rel(run.cmd_t, t0), cmd[:, i], color="C1", label="command (sent)")
        if len(eta):
            a.plot(_rel(run.fb_t, t0), eta[:, i], color="C0", lw=0.8, label="NAO (measured)")
        if len(ze):
            a.plot(_rel(run.ze_t, t0), ze[:, i], color="C2", lw=1.0, ls="--", label="z_e (felt, eq. 29)")
        a.set_ylabel(f"{name} [{unit}]")
        shade(a)
        shade_fv(a)
        a.legend(loc="upper right", fontsize=8)
    a = axes[2]
    if len(fva):
        a.plot(_rel(fv_t, t0), fva[:, 0], color="C3", label="f_v tangential")
        a.plot(_rel(fv_t, t0), fva[:, 1], color="C7", lw=0.8, label="f_v normal")
    a.set_ylabel("fictitious force f_v")
    shade(a)
    shade_fv(a)
    a.legend(loc="upper right", fontsize=8)
    a = axes[3]
    force_t, force = (run.force_t, run.force) if run.force else (run.state_force_t, run.state_force)
    if force:
        f = np.asarray(force)
        a.plot(_rel(force_t, t0), f[:, 0], color="C4", label="f_m forward axis")
        a.plot(_rel(force_t, t0), f[:, 1], color="C5", label="f_m turn axis")
    a.set_ylabel("handle force [N]")
    a.set_xlabel("time [s]")
    shade(a)
    shade_fv(a)
    a.legend(loc="upper right", fontsize=8)
    axes[0].set_title("Coordination: (a) forward, (b) turn, (c) fictitious force, (d) handle force")
    return fig


def _fig12_tracking(figure: type[Figure], run: Run, t0: float, shade: Callable[[Any], None]) -> Figure:
    """Fig. 12: applied reference vs robot, forward speed and turn angle."""
    fig = figure(figsize=(8, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    if run.fb_t:
        eta = np.asarray(run.fb_eta, dtype=float).reshape(-1, 2)
        tr = _rel(run.fb_t, t0)
        ref = np.asarray(run.fb_ref)
        axes[0].plot(tr, ref[:, 0], color="C1", label="reference (on the robot)")
        axes[0].plot(tr, eta[:, 0], color="C0", lw=0.8, label="NAO")
        dt = np.diff(tr, prepend=tr[0])
        ref_angle = np.cumsum(ref[:, 1] * dt)
        axes[1].plot(tr, ref_angle, color="C1", label="reference angle (integral)")
        yaw = np.asarray(run.fb_yaw, dtype=float)
        ok = np.isfinite(yaw)
        if ok.any():
            yaw_deg = np.degrees(np.unwrap(yaw[ok]))
            axes[1].plot(tr[ok], yaw_deg - yaw_deg[0], color="C0", lw=0.8, label="NAO yaw")
        for a in axes:
            a.legend(loc="upper right", fontsize=8)
    axes[0].set_ylabel("forward speed [cm/s]")
    axes[1].set_ylabel("turn angle [deg]")
    axes[1].set_xlabel("time [s]")
    for a in axes:
        shade(a)
    axes[0].set_title("Tracking: (a) forward speed, (b) turn angle")
    return fig
