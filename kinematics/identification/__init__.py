"""Identification shared by classical calibration and the gap workflow.

Modules: ``conditions`` (dataset -> observations: the per-point conditions effects depend on
and the measured poses) and ``fitting`` (least squares over effects with analytic pose
Jacobians). :mod:`kinematics.calibration` and :mod:`kinematics.gap` both build on them;
neither imports the other's folder for them.
"""
