"""Simulated captures: a face mesh driven by a weight performance, seen by markers."""

from mocap.synth.capture import CaptureTruth, SimulatedCapture, load_capture_truth, simulate_capture

__all__ = ["CaptureTruth", "SimulatedCapture", "simulate_capture", "load_capture_truth"]
