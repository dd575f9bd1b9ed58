"""A Take saved as a NumPy ``.npz`` archive (lossless, our own format)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mocap.errors import FileFormatError
from mocap.take import Analog, SourceInfo, Take
from mocap.util.atomic import atomic_path
from mocap.util.npz import read_npz_with_meta

__all__ = ["read_take_npz", "write_take_npz"]

_FORMAT = "mocap2mesh-take-1"


def write_take_npz(take: Take, path, *, inputs=()) -> None:
    """Write `take` to `path` (``.npz``), atomically.

    Positions are stored in mm as float64 with NaN for missing samples.
    """
    source = {k: v for k, v in vars(take.source).items() if k != "extra"}
    arrays = dict(positions=take.positions, filled=take.filled,
                  labels=np.array(take.labels, dtype=str),
                  meta=np.array(json.dumps({
                      "format": _FORMAT, "rate": take.rate,
                      "first_frame": take.first_frame, "source": source})))
    if take.analog is not None:
        arrays.update(analog_values=take.analog.values,
                      analog_labels=np.array(take.analog.labels, dtype=str),
                      analog_units=np.array(take.analog.units, dtype=str),
                      analog_rate=np.array(take.analog.rate))
    with atomic_path(path, inputs=inputs) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)


def read_take_npz(path) -> Take:
    """Read a take written by :func:`write_take_npz`.

    Raises
    ------
    FileFormatError
        If the file is not such an archive or is damaged.
    """
    path = Path(path)
    meta, z = read_npz_with_meta(path, "mocap2mesh take archive", _FORMAT,
                                 required=("labels", "positions", "filled"))
    try:
        analog = None
        if "analog_values" in z:
            analog = Analog(z["analog_values"], float(z["analog_rate"]),
                            tuple(z["analog_labels"]), tuple(z["analog_units"]))
        source = SourceInfo(**{**meta["source"], "path": str(path)})
        return Take(tuple(z["labels"]), z["positions"], meta["rate"],
                    first_frame=meta["first_frame"], filled=z["filled"],
                    source=source, analog=analog)
    except (ValueError, KeyError, TypeError) as exc:
        raise FileFormatError(path, f"cannot read take archive: {exc}") from None
