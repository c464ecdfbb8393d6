"""SAGE: world-model ensemble, fear, curiosity, threshold, gate and the fear-regularised learners."""
