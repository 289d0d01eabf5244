"""Benchmarks: speed and accuracy side by side, stability sweeps, bounds."""
