"""Retargeting: marker displacements drive a face mesh through an RBF operator."""
