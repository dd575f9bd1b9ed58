"""Cleaning of marker tracks: swap repair, implausible samples, gap filling, low-pass
filtering, resampling."""

from .filtering import lowpass
from .gapfill import FILL_OPTIONS, FillResult, fill_gaps
from .outliers import (ImplausibleSamples, find_implausible_samples,
                       remove_implausible_samples)
from .resampling import resample
from .swaps import LabelSwap, find_label_swaps, fix_label_swaps

__all__ = ["fill_gaps", "FillResult", "FILL_OPTIONS", "lowpass", "resample",
           "LabelSwap", "find_label_swaps", "fix_label_swaps", "ImplausibleSamples",
           "find_implausible_samples", "remove_implausible_samples"]
