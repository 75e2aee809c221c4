"""``calibrated`` on the machine sensor set: identify the machine from a few known-payload motions.

A service technician's set-up: a roughly right machine file (``cat345c-hydraulic-3pct``: every
number 3 % off), a handful of calibration motions with known payloads, then weighing; later a
short empty-bucket motion re-estimates the sensor offsets (``excavator-payload zero``). One room
per job:

* :mod:`.settings`: what is identified (parameters, offsets, IMU dynamics), priors, windows
  and the ``--option`` choices;
* :mod:`.symbolic`: the residuals and the streaming kernels' functions, from the CasADi model;
* :mod:`.data`: accelerations, noise from the data, momentum windows, glitches, the IMUs' leak,
  the angles covered;
* :mod:`.solver`: :class:`~.solver.MachineCalibration`, ``calibrate``, ``zero_offsets`` and
  the two-fold cross-check;
* :mod:`.kernel`: :class:`~.kernel.CalibratedKernel`, the streaming weighing;
* :mod:`.weighing`: :class:`~.weighing.MachineWeighing`, what the estimator holds (fit, zero,
  save, restore) and the notes ``estimate`` adds.

What was measured with each choice is in ``docs/findings/machine-weighing.md``. The package
imports none of its rooms here (each is imported by its own path).
"""
