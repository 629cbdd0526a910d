"""Plots of a report's rows (:class:`calib.report.rows.ReportRows`), drawn with
matplotlib's Agg canvas (no display; pyplot and the global backend are left alone), fixed
layouts (no constrained layout: it cost seconds per figure), and readable at any number of rows:
above :data:`THIN_ABOVE` rows the per-row curves become per-bin envelopes (median and largest
error of each bin of rows), the workspace map shows a thinned subset that keeps the worst rows,
and outliers are always drawn one by one.

- ``position_errors.png``: per file row, the position error before (the registered nominal model)
  and after calibration, mm; calibration and validation rows in two colours, outliers marked with
  a red cross, the tolerance as a dashed line.
- ``orientation_errors.png``: the same for the orientation error, degrees (pose data only).
- ``error_histograms.png``: histograms of the position (and orientation) errors after
  calibration, outliers left out (their count in the legend).
- ``error_map.png``: the error after calibration against the reach (distance of the measured point
  from the base frame's origin) and over the workspace seen from above (x, y in the base frame,
  coloured by the error).
- ``drift.png``: the error after calibration against time and temperature, when the rows have them.
"""
from __future__ import annotations

import io
import math
from typing import Collection, Mapping

import numpy as np

from calib.report.rows import ReportRows, drift_columns

__all__ = ["PLOT_FILES", "THIN_ABOVE", "plot_names", "plot_rows", "warm_up"]

#: File names of the plots, in the order :func:`plot_rows` returns them.
PLOT_FILES = ("position_errors.png", "orientation_errors.png", "error_histograms.png", "error_map.png",
              "drift.png")
#: Above this many rows the per-row curves are drawn as per-bin envelopes.
THIN_ABOVE = 3000
#: Number of bins of the envelopes; points of the thinned workspace scatter.
BINS, SCATTER_POINTS = 400, 3000
DPI = 90
_DEG = 180.0 / math.pi
_CAL, _VAL, _OUT = "tab:blue", "tab:orange", "red"


def warm_up() -> None:
    """Import what drawing needs (matplotlib's figure and Agg canvas, about 0.35 s), so that a
    process that will draw can pay for it while it waits for the rows (calib.cli.plot_worker)."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401


def _png(fig) -> bytes:
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    for ax in fig.axes:          # fewer ticks: each is a Line2D and a Text, most of a plot's cost
        ax.locator_params(nbins=6)
    buf = io.BytesIO()
    # glyphs rendered without the font's hinting program (FreeType's TrueType interpreter ran
    # for every glyph drawn: 14 % of drawing a plot); the text is as legible, a little softer
    with rc_context({"text.hinting": "no_hinting"}):
        fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": 1})   # (level 6: +40 ms a plot)
    return buf.getvalue()


def _figure(w: float, h: float, **adjust):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h))
    fig.subplots_adjust(**{"left": 0.07, "right": 0.98, "top": 0.9, "bottom": 0.1, "hspace": 0.45,
                           "wspace": 0.25, **adjust})
    return fig


def _envelope(ax, x: np.ndarray, e: np.ndarray, color: str, label: str) -> None:
    """Per bin of consecutive points (x sorted): the median as a line, the range up to the largest
    as a band."""
    order = np.argsort(x, kind="stable")
    x, e = x[order], e[order]
    edges = np.linspace(0, len(x), min(BINS, len(x)) + 1).astype(int)
    starts = edges[:-1]
    xm = np.add.reduceat(x, starts) / np.diff(edges)
    hi = np.maximum.reduceat(e, starts)
    lo = np.minimum.reduceat(e, starts)
    med = np.array([np.median(e[a:b]) for a, b in zip(edges[:-1], edges[1:])])
    ax.fill_between(xm, lo, hi, color=color, alpha=0.25, lw=0, label=f"{label}: range per bin")
    ax.plot(xm, med, color=color, lw=1.0, label=f"{label}: median per bin")


def _groups(rows: ReportRows, extra=None) -> list[tuple[str, np.ndarray, str]]:
    """The colour groups of the rows (outliers apart): calibration and validation rows of a
    calibration; cal and val rows (or all rows) of one model's evaluation."""
    kept = ~rows.outlier if extra is None else ~rows.outlier & extra
    if rows.before is None:                   # one model's evaluation
        parts = [("cal rows", rows.sets == "cal"), ("val rows", rows.sets == "val")]
        if not all(m.any() for _, m in parts):
            parts = [("rows", np.ones(rows.n_rows, bool))]
    else:
        parts = [("calibration rows", ~rows.validation), ("validation rows", rows.validation)]
    return [(name, m & kept, color) for (name, m), color in zip(parts, (_CAL, _VAL)) if (m & kept).any()]


def _after(rows: ReportRows) -> str:
    return "after calibration" if rows.before is not None else "of the model"


def _clip_outliers(ax, x: np.ndarray, e: np.ndarray, mask: np.ndarray, unit: str, kept_max: float,
                   tolerance=None) -> dict:
    """The outliers of ``mask`` as red crosses, those above the scale of the kept rows drawn at
    the top edge with their value (the kept rows keep a readable scale). Returns the keyword
    arguments of the axes' legend: upper right, lowered below the top edge's markers when there
    are any (a legend there hid them)."""
    top = max(kept_max, tolerance or 0.0) * 1.3 or 1.0
    ax.set_ylim(0, top)
    legend = {"loc": "upper right"}
    if not mask.any():
        return legend
    xs, es = x[mask], e[mask]
    inside = es <= top
    label = f"outliers ({int(mask.sum())}, left out of the fit)"
    if inside.any():
        ax.plot(xs[inside], es[inside], ls="none", marker="x", ms=7, mew=1.5, color=_OUT, label=label)
        label = None
    if (~inside).any():
        ax.plot(xs[~inside], np.full((~inside).sum(), top * 0.97), ls="none", marker="^", ms=7, color=_OUT,
                label=label if label is None else label + ", off scale")
        off = es[~inside]
        ax.text(0.01, 0.95, "off scale: " + ", ".join(f"{v:.3g}" for v in off[:8]) + (" ..." if len(off) > 8 else "")
                + f" {unit}", transform=ax.transAxes, fontsize=7.5, color=_OUT, va="top")
        legend["bbox_to_anchor"] = (1.0, 0.93)
    return legend


def _per_row(rows: ReportRows, attr: str, scale: float, unit: str, name: str, tolerance=None) -> bytes:
    panels = [(_after(rows), rows.after)]
    if rows.before is not None:
        panels.insert(0, (f"before calibration ({rows.before_label})", rows.before))
    # one panel per model: an evaluation (one model) drew an empty second panel below its own
    fig = _figure(11, 6.4, top=0.88) if len(panels) == 2 else _figure(11, 3.6, top=0.88, bottom=0.15)
    axes = np.atleast_1d(fig.subplots(len(panels), 1))
    thin = rows.n_rows > THIN_ABOVE
    x = rows.row.astype(float)
    groups = _groups(rows)
    for ax, (label, dev) in zip(axes, panels):
        e = getattr(dev, attr) * scale
        for gname, mask, color in groups:
            marker = np.where(rows.file[mask] == "validation", "^", ".")
            if thin:
                _envelope(ax, x[mask], e[mask], color, gname)
            else:
                for mk in np.unique(marker):
                    sel = marker == mk
                    ax.plot(x[mask][sel], e[mask][sel], ls="none", marker=mk, ms=4 if mk == "." else 3,
                            color=color, label=gname + (" (validation file)" if mk == "^" else ""))
        tol = tolerance * scale if tolerance is not None and attr == "position_errors" else None
        if tol is not None:
            ax.axhline(tol, color="black", ls="--", lw=0.8, label=f"tolerance {tol:g} {unit}")
        kept = ~rows.outlier
        legend = _clip_outliers(ax, x, e, rows.outlier, unit, float(e[kept].max()) if kept.any() else 0.0, tol)
        # the figures of the accuracy table: all calibration rows before, without the outliers after
        judged = rows.calibration & (kept if dev is rows.after else True)
        if rows.before is None or not judged.any():
            judged = kept
        what = "calibration rows" if rows.before is not None else "rows"
        ax.set_title(f"{name}, {label}: {what} RMS {np.sqrt(np.mean(e[judged] ** 2)):.4g} {unit}, max "
                     f"{e[judged].max():.4g} {unit} ({int(judged.sum())} rows"
                     + (", without the outliers)" if dev is rows.after and rows.outlier.any() else ")"),
                     fontsize=9.5)
        ax.set_xlabel(rows.x_label(), fontsize=9)
        ax.set_ylabel(f"{name} / {unit}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7.5, ncol=2, **legend)
    return _png(fig)


def _histograms(rows: ReportRows) -> bytes:
    """Histograms of the errors after calibration (position, and orientation for pose data),
    calibration and validation rows apart, outliers left out (counted in the legend)."""
    quantities = [("position_errors", 1e3, f"{rows.quantity} {_after(rows)} / mm")]
    if rows.has_rotation:
        quantities.append(("rotation_errors", _DEG, f"orientation error {_after(rows)} / deg"))
    fig = _figure(11, 3.4, top=0.86, bottom=0.16)
    axes = np.atleast_1d(fig.subplots(1, len(quantities)))
    for ax, (attr, scale, xlabel) in zip(axes, quantities):
        e = getattr(rows.after, attr) * scale
        data = [(name, e[mask], color) for name, mask, color in _groups(rows)]
        hi = max(float(v.max()) for _, v, _ in data)
        bins = np.linspace(0.0, hi * 1.0001 if hi > 0 else 1.0, 41)
        for name, v, color in data:
            counts, _ = np.histogram(v, bins=bins)
            ax.stairs(counts, bins, fill=True, alpha=0.55, color=color, label=f"{name} ({len(v)})")
        if rows.outlier.any():
            ax.plot([], [], ls="none", marker="x", color=_OUT, label=f"{int(rows.outlier.sum())} outliers not shown")
        ax.set_xlabel(xlabel, fontsize=9)
        ax.set_ylabel("rows", fontsize=9)
        ax.legend(fontsize=7.5)
        ax.grid(alpha=0.3)
    fig.suptitle(f"Distribution of the tool pose errors {_after(rows)}")
    return _png(fig)


def _thin_index(e: np.ndarray, n: int) -> np.ndarray:
    """Indices of at most ``n`` rows: a regular stride plus the largest errors."""
    if len(e) <= n:
        return np.arange(len(e))
    worst = np.argpartition(e, -n // 10)[-n // 10:]
    stride = np.linspace(0, len(e) - 1, n - len(worst)).astype(int)
    return np.union1d(stride, worst)


def _error_map(rows: ReportRows, tolerance=None) -> bytes:
    fig = _figure(11, 4.8, left=0.07, right=0.95, top=0.86, bottom=0.12, wspace=0.15)
    e = rows.after.position_errors * 1e3
    kept = ~rows.outlier
    reach = rows.reach * 1e3
    ax = fig.add_subplot(1, 2, 1)
    if rows.n_rows > THIN_ABOVE:
        _envelope(ax, reach[kept], e[kept], _CAL, "rows")
    else:
        for name, mask, color in _groups(rows):
            ax.plot(reach[mask], e[mask], ls="none", marker=".", ms=4, color=color, label=name)
    if tolerance is not None:
        ax.axhline(tolerance * 1e3, color="black", ls="--", lw=0.8, label="tolerance")
    legend = _clip_outliers(ax, reach, e, rows.outlier, "mm", float(e[kept].max()) if kept.any() else 0.0,
                            None if tolerance is None else tolerance * 1e3)
    ax.set_xlabel("reach: distance of the measured point from the base frame origin / mm", fontsize=9)
    ax.set_ylabel(f"{rows.quantity} {_after(rows)} / mm", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7.5, **legend)
    ax.set_title("error against reach", fontsize=9.5)
    ax2 = fig.add_subplot(1, 2, 2)
    idx = _thin_index(np.where(kept, e, -1.0), SCATTER_POINTS)
    idx = idx[kept[idx]]
    idx = idx[np.argsort(e[idx], kind="stable")]          # the largest errors drawn last, on top
    p = rows.point_base[idx] * 1e3
    sc = ax2.scatter(p[:, 0], p[:, 1], c=e[idx], cmap="viridis", s=10, lw=0)
    if rows.outlier.any():
        po = rows.point_base[rows.outlier] * 1e3
        ax2.plot(po[:, 0], po[:, 1], ls="none", marker="x", ms=7, mew=1.5, color=_OUT, label="outliers")
        ax2.legend(fontsize=7.5)
    ax2.set_aspect("equal", adjustable="datalim")
    cb = fig.colorbar(sc, ax=ax2, shrink=0.9, pad=0.02)
    cb.set_label(f"{rows.quantity} / mm", fontsize=9)
    ax2.set_xlabel("x in the base frame / mm", fontsize=9)
    ax2.set_ylabel("y in the base frame / mm", fontsize=9)
    ax2.grid(alpha=0.3)
    shown = f"{len(idx)} of {int(kept.sum())} rows" if len(idx) < kept.sum() else f"{len(idx)} rows"
    ax2.set_title(f"measured points seen from above ({shown})", fontsize=9.5)
    fig.suptitle(f"{rows.quantity.capitalize()} {_after(rows)} over the workspace")
    return _png(fig)


_AXIS_NAMES = {"time_s": ("time", "s"), "temperature_c": ("temperature", "°C")}


def _drift(rows: ReportRows, columns: Mapping[str, np.ndarray]) -> bytes:
    names = list(columns)
    fig = _figure(11, 3.6, top=0.84, bottom=0.16)
    axes = np.atleast_1d(fig.subplots(1, len(names)))
    e = rows.after.position_errors * 1e3
    kept = ~rows.outlier
    for ax, name in zip(axes, names):
        v = columns[name]
        ok = kept & np.isfinite(v)
        if ok.sum() > THIN_ABOVE:
            _envelope(ax, v[ok], e[ok], _CAL, "rows")
        else:
            for gname, mask, color in _groups(rows, ok):
                ax.plot(v[mask], e[mask], ls="none", marker=".", ms=4, color=color, label=gname)
        if ok.sum() >= 3 and np.ptp(v[ok]) > 0:
            slope, icpt = np.polyfit(v[ok], e[ok], 1)
            xs = np.array([v[ok].min(), v[ok].max()])
            quantity, unit = _AXIS_NAMES.get(name, (name, ""))
            ax.plot(xs, icpt + slope * xs, color="black", lw=1, label=f"trend {slope:.3g} mm per {unit}")
        quantity, unit = _AXIS_NAMES.get(name, (name, ""))
        ax.set_xlabel(f"{quantity} / {unit}" if unit else quantity, fontsize=9)
        ax.set_ylabel(f"{rows.quantity} {_after(rows)} / mm", fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7.5)
    fig.suptitle(f"Drift during the measurement: error {_after(rows)} against "
                 + " and ".join(_AXIS_NAMES.get(n, (n,))[0] for n in names))
    return _png(fig)


def _jobs(rows: ReportRows, tolerance_m: float | None, columns: Mapping[str, np.ndarray] | None) -> list:
    """The plots of ``rows`` (see :func:`plot_rows`): (file name, function drawing its PNG)."""
    jobs = [("position_errors.png", lambda: _per_row(rows, "position_errors", 1e3, "mm", rows.quantity,
                                                     tolerance_m))]
    if rows.has_rotation:
        jobs.append(("orientation_errors.png",
                     lambda: _per_row(rows, "rotation_errors", _DEG, "deg", "orientation error")))
    jobs.append(("error_histograms.png", lambda: _histograms(rows)))
    jobs.append(("error_map.png", lambda: _error_map(rows, tolerance_m)))
    if columns is None:
        columns = drift_columns(rows)
    if columns:
        jobs.append(("drift.png", lambda: _drift(rows, columns)))
    return jobs


def plot_names(rows: ReportRows, columns: Mapping[str, np.ndarray] | None = None) -> list[str]:
    """The file names of the plots :func:`plot_rows` draws of ``rows`` (and ``columns``), in order."""
    return [name for name, _ in _jobs(rows, None, columns)]


def plot_rows(rows: ReportRows, *, tolerance_m: float | None = None,
              columns: Mapping[str, np.ndarray] | None = None, progress=None,
              names: Collection[str] | None = None) -> dict[str, bytes]:
    """PNG images of a report's rows by file name (module docstring); ``orientation_errors.png``
    only for pose data, ``drift.png`` only with ``columns`` (name with unit -> (N,) values;
    default: the rows' ``time_s`` and ``temperature_c`` when they have them).
    progress : called with the number of plots done after each (for a progress line).
    names : draw only these of the plots (the others are left out: a worker process drawing its
    share of them, calib.cli.plot_worker)."""
    jobs = _jobs(rows, tolerance_m, columns)
    if names is not None:
        jobs = [(name, job) for name, job in jobs if name in names]
    images = {}
    for k, (name, job) in enumerate(jobs):
        images[name] = job()
        if progress is not None:
            progress(k + 1, len(jobs))
    return images
