"""Evaluation, experiment recipes and benchmarks built on mosaic_data and mosaic_policy."""
