"""Cleaning of marker tracks: swap repair, implausible samples, gap filling, low-pass
filtering, resampling."""

from mocap.clean.filtering import lowpass
from mocap.clean.gapfill import FILL_OPTIONS, FillResult, fill_gaps
from mocap.clean.outliers import (
                       ImplausibleSamples,
                       find_implausible_samples,
                       remove_implausible_samples,
)
from mocap.clean.resampling import resample
from mocap.clean.swaps import LabelSwap, find_label_swaps, fix_label_swaps

__all__ = ["fill_gaps", "FillResult", "FILL_OPTIONS", "lowpass", "resample",
           "LabelSwap", "find_label_swaps", "fix_label_swaps", "ImplausibleSamples",
           "find_implausible_samples", "remove_implausible_samples"]
