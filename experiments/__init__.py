"""Investigations of the gate and the fear term (not speed benchmarks): run each as ``python -m experiments.NAME``
from the repository root; the index is experiments/README.md."""
