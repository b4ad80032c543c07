"""Experiments: the paper's tables and figures (``reproduce``), the demo, plots and reports.
Depends on ``world``, ``envs``, ``model`` and ``learn``."""
