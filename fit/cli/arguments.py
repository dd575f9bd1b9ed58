"""Arguments that several subcommands share, declared once.

Each ``add_*`` function adds one argument (or a small group that always goes
together) to a subcommand's parser, with the same name, type and help
everywhere; a command passes only what differs (whether it is required, a
sentence of help about its own use).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mocap.clean.ingest import FILL_CHOICES
from mocap.neutral import HOLD_S, PICKED_FRAMES

__all__ = ["parse_frame", "add_capture", "add_markerset", "add_mesh", "add_landmarks",
           "add_binding", "add_units", "add_fill", "add_neutral_frame"]

#: What each neutral-frame choice means, for the help of every command that takes one.
NEUTRAL_FRAME_HELP = ("the neutral frame by the capture's own frame number (as the weights CSV, "
                      "the report and the manifest number them), 'auto' (default): the frame closest "
                      "to the median pose after head stabilization, or 'hold': the mean pose "
                      f"of the first still {HOLD_S:g} s of the neutral hold the take starts "
                      "with (averaged in the head frame)")


def parse_frame(text: str):
    """``"auto"``, ``"hold"`` or a frame number >= 0 (an argparse type).

    Examples
    --------
    >>> parse_frame("hold"), parse_frame("12")
    ('hold', 12)
    """
    if text in PICKED_FRAMES:
        return text
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame number, 'auto' or 'hold', got {text!r}") \
            from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"a frame number is >= 0, got {value}")
    return value


def add_capture(parser, name: str = "capture") -> None:
    """The positional capture file."""
    parser.add_argument(name, type=Path, help="C3D, Vicon Nexus CSV, TRC or .npz take")


def add_markerset(parser, *, required: bool = True,
                  help: str = "marker-set TOML (head markers, regions, landmarks)") -> None:
    """``--markerset``."""
    parser.add_argument("--markerset", required=required, type=Path, help=help)


def add_mesh(parser, *, required: bool = True, help: str = "neutral face mesh") -> None:
    """``--mesh``."""
    parser.add_argument("--mesh", required=required, type=Path, help=help)


def add_landmarks(parser, *, required: bool = True) -> None:
    """``--landmarks``: the mesh landmarks."""
    parser.add_argument("--landmarks", required=required, type=Path,
                        help="mesh-landmark TOML (anatomical point = vertex id)")


def add_binding(parser, *, required: bool = True,
                help: str = "binding .json from 'mocap2mesh bind' (same mesh)") -> None:
    """``--binding``."""
    parser.add_argument("--binding", required=required, type=Path, help=help)


def add_units(parser, *, help: str = "units of the mesh file (e.g. cm)") -> None:
    """``--units`` of a mesh file that does not say."""
    parser.add_argument("--units", help=help)


def add_fill(parser, *,
             help: str = "gap-filling method (default auto; 'none' keeps the gaps)") -> None:
    """``--fill`` and ``--max-gap``."""
    parser.add_argument("--fill", choices=FILL_CHOICES, default="auto", help=help)
    parser.add_argument("--max-gap", type=int, metavar="FRAMES",
                        help="longest gap to fill (default 0.1 s of frames at the take's "
                             "rate; longer gaps are reported, not filled)")


def add_neutral_frame(parser, flag: str = "--frame", *, help: str = NEUTRAL_FRAME_HELP) -> None:
    """The neutral frame: an index, ``auto`` or ``hold`` (:func:`mocap.neutral.find_neutral`)."""
    parser.add_argument(flag, type=parse_frame, default="auto", metavar="N|auto|hold", help=help)
