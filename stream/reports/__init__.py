"""Reports and file outputs of the CLI: Markdown, PNG plots, Rerun ``.rrd`` recordings and the
model, state and table files the learner and gap workflows return as values.

The cores (``kinematics``, ``learner``) compute; only modules here (and the stages) write.
"""
