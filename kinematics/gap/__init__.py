"""The sim-vs-measured discrepancy workflow: where model and measurement disagree, which
effect of the vocabulary is missing, and how far adding it closes the gap.

Modules: ``conditions`` (dataset -> observations), ``fitting`` (least squares over effects
with analytic pose Jacobians), ``regions`` (residuals by region vs the noise floor),
``candidates`` (signatures and tests of missing effects), ``workflow`` (the loop,
:func:`~kinematics.gap.workflow.run_gap`), ``model_file`` (the updated model as TOML),
``report`` (Markdown, plots, Rerun recording) and ``files`` (file-level entry points).
They are imported by name (``from kinematics.gap.workflow import run_gap``); this package
imports none of them so that :mod:`kinematics.calibration` can use ``fitting`` freely.
"""
