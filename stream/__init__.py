"""The streaming pipeline: the Zenoh bus, sources, the event-time window, the learner stage,
the compensation service, the Rerun dashboard, MCAP record/replay, the daemon and the CLI.
(The wire messages and key expressions are in ``wire/``, below ``sim_sources/``.)

Pure cores (window, points, learner_core, compensation) take and return typed values;
the stages in ``stream.stages`` are thin Zenoh shells around them; ``stream.daemon`` composes
the stages from a ``stream.config.DaemonConfig``.
"""
