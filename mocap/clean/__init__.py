"""Cleaning of marker tracks: gap filling, low-pass filtering, resampling."""

from .filtering import lowpass
from .gapfill import FILL_OPTIONS, FillResult, fill_gaps
from .resampling import resample

__all__ = ["fill_gaps", "FillResult", "FILL_OPTIONS", "lowpass", "resample"]
