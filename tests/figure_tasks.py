"""Figures for the tests of :class:`fit.report.figure_queue.FigureQueue`: module-level so
that they pickle by name into a helper process."""

from __future__ import annotations

import gc
import json
import os
import warnings

import matplotlib.pyplot as plt
import numpy as np

from mocap.errors import FileFormatError


def lines(path, seed: int) -> None:
    """A figure of random lines and text, its look taken from the rcParams."""
    points = np.random.default_rng(seed).normal(size=(50, 2))
    figure, axes = plt.subplots(figsize=(3, 2))
    axes.plot(points[:, 0], points[:, 1])
    axes.set_title(f"seed {seed}")
    figure.savefig(path)
    plt.close(figure)


def pid(path) -> None:
    """Write the drawing process's id."""
    with open(path, "w") as out:
        out.write(str(os.getpid()))


def collector(path) -> None:
    """Write the drawing process's id and its garbage collector's state."""
    with open(path, "w") as out:
        json.dump({"pid": os.getpid(), "enabled": gc.isenabled(),
                   "frozen": gc.get_freeze_count(),
                   "collections": [g["collections"] for g in gc.get_stats()]}, out)


def bad_file(path) -> None:
    raise FileFormatError(path, "not a figure", offset=7)


def warned(path) -> None:
    warnings.warn(f"careful with {os.path.basename(path)}", UserWarning)
    pid(path)


def dies_in_helper(path, caller: int) -> None:
    """Kill the helper that draws it; drawn by the caller, write its pid."""
    if os.getpid() != caller:
        os._exit(3)
    pid(path)


class PickyError(Exception):
    """Pickles, but does not unpickle: its constructor wants a keyword argument."""

    def __init__(self, path, *, why: str):
        super().__init__(f"{path}: {why}")


def picky(path) -> None:
    raise PickyError(path, why="no figure")
