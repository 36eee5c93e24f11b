"""Application layer: scenario files -> objects (parser, builders, policy registry), runner, results,
figures, viewer and the ``hqp-tpm`` command line.

May import every layer below it; nothing below imports it. Its modules are imported on use (matplotlib,
meshcat and tqdm load only when a figure, a replay or a progress bar is asked for).
"""
