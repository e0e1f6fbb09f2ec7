"""Test problems with exact ground truth and no downloads: shapes, procedural characters and pairs.

Uses only :mod:`ncflow.geometry`, :mod:`ncflow.io` and :mod:`ncflow.skeleton` (docs/architecture.md,
"Layers and the import rule"), so the generators do not depend on the method they are used to test.
"""
