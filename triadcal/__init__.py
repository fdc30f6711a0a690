"""triadcal: probabilistic calibration of accelerometer triads.

Layout (data flows one way):
    models/      physics only: bench kinematics, eq. 1, switchable effects, simulator
    estimation/  classical (eq. 2-3), joint least squares, budget (eq. 4-7), ...
    hardware/    serial capture, drivers, emulator
    reports/     certificates and plots
    cli/         the ``triadcal`` command, thin over :mod:`triadcal.api`
"""

__version__ = "0.1.0"
