"""The sim-vs-measured discrepancy workflow: where model and measurement disagree, which
effect of the vocabulary is missing, and how far adding it closes the gap.

Modules: ``regions`` (residuals by region vs the noise floor), ``candidates`` (signatures
and tests of missing effects), ``formed`` and ``naming`` (effects formed from the residual and
their names), ``workflow`` (the loop, :func:`~kinematics.gap.workflow.run_gap`),
``model_file`` (the updated model as TOML) and ``files`` (file-level entry points). Observations
and fitting are shared with calibration (:mod:`kinematics.identification`); the report (Markdown,
plots, Rerun recording) is written by :mod:`stream.reports.gap`. They are imported by name
(``from kinematics.gap.workflow import run_gap``).
"""
