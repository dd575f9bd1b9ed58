"""Cleaning of marker tracks: gap filling, low-pass filtering, resampling."""

from .filtering import lowpass
from .gapfill import FILL_OPTIONS, FillResult, fill_gaps
from .resampling import resample
from .swaps import LabelSwap, find_label_swaps, fix_label_swaps

__all__ = ["fill_gaps", "FillResult", "FILL_OPTIONS", "lowpass", "resample",
           "LabelSwap", "find_label_swaps", "fix_label_swaps"]
