"""Runs and their artifacts: the content-addressed cache, the paper grid, the front, the
cached steps notebooks call."""
