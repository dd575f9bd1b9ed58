"""The coverage of a PCA model: how much of the variance its first m components hold, as a plot."""

from __future__ import annotations

import numpy as np
from matplotlib.ticker import FuncFormatter, LogLocator

from mocap.errors import InputError
from mocap.viz.figures import distinct_colours, new_figure, save_figure

__all__ = ["plot_coverage"]


def plot_coverage(model, path, *, thresholds=(0.99, 0.995), title: str | None = None) -> None:
    """Cumulative PCA coverage against the number of components m (PNG).

    Parameters
    ----------
    model : basis.pca.PCAModel or array_like, shape (m,)
        Its ``coverage_curve()`` (fraction of the total variance of every component
        whose eigenvalue it knows), or that coverage.
    path : str or os.PathLike
    thresholds : sequence of float in (0, 1]
        Drawn as horizontal lines, with the smallest m reaching each marked
        (or "not reached with the m kept").
    """
    cov = np.asarray(model.coverage_curve() if hasattr(model, "coverage_curve") else model,
                     dtype=float)
    thresholds = [float(t) for t in thresholds]
    if not all(0 < t <= 1 for t in thresholds):
        raise InputError(f"thresholds must be in (0, 1], got {thresholds}")
    m = np.arange(1, len(cov) + 1)
    fig = new_figure(12, 4.5)
    covered, uncovered = fig.subplots(1, 2)
    covered.plot(m, 100 * cov, "o-", ms=3, lw=1, color="black")
    rest = 100 * (1 - cov)
    shown = rest > 1e-9 * rest[0]        # the last components can cover "all" to rounding
    uncovered.semilogy(m[shown], rest[shown], "o-", ms=3, lw=1, color="black")
    for threshold, colour in zip(thresholds, distinct_colours(len(thresholds) + 1)[1:]):
        reached = np.nonzero(cov >= threshold * (1 - 1e-12))[0]
        covered.axhline(100 * threshold, color=colour, lw=0.8, ls="--")
        uncovered.axhline(100 * (1 - threshold), color=colour, lw=0.8, ls="--")
        if reached.size:
            k = int(reached[0]) + 1
            label = f"{100 * threshold:g} % reached at m = {k}"
            for ax, y in ((covered, 100 * cov[k - 1]), (uncovered, rest[k - 1])):
                ax.axvline(k, color=colour, lw=0.8, ls=":")
                ax.plot(k, y, "o", color=colour, ms=7)
        else:
            label = f"{100 * threshold:g} % not reached with m = {len(cov)}"
        covered.plot([], [], "o--", color=colour, label=label)
    covered.set_ylim(top=100.5)
    covered.set_ylabel("variance covered (%)")
    uncovered.set_ylabel("variance not covered, 100 − coverage (%)")
    uncovered.yaxis.set_major_locator(LogLocator(numticks=12))
    uncovered.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    covered.legend(loc="lower right", fontsize=8)
    for ax in (covered, uncovered):
        ax.set_xlim(0.5, len(cov) + 0.5)
        ax.set_xlabel("number of components m")
        ax.grid(alpha=0.3, which="both")
    fig.suptitle(title or f"PCA coverage of the first {len(cov)} components")
    save_figure(fig, path)
