"""The paper's studies and the measurements around them: protocols, defaults, tables and figures.

Layers point down only: ``core`` < ``sims`` < ``studies`` < ``app``. A study composes simulators (through their
descriptors) and learners; the app's commands are thin adapters over it.

- :mod:`studies.spec` and :mod:`studies.training`: ``TrainSpec`` and ``run_training(spec)``, the composition root
  of one training run (``sage train`` is a thin adapter over them), and the study protocols around it.
- :mod:`studies.envs`: what a ``--scenario`` string means (the simulators' descriptors).
- :mod:`studies.route_shift` and :mod:`studies.route_shift_figures`: the SUMO route-shift protocol, its panels.
- :mod:`studies.highway`: CAT-style closed-loop adversarial training and the normal / adversarial table.
- :mod:`studies.cycles` and :mod:`studies.cycles_figures`: deploy -> takeover -> fine-tune cycles.
- :mod:`studies.calibrate`: does fear predict danger? (``sage gate evaluate``)
"""
