"""The loop, experts, reports and learners. Knows nothing of ``sims`` or ``app``."""
