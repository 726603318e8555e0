"""Composition and execution: the episode stage, the Dask build, the closed loop, the CLI."""
