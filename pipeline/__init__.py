"""Composition and execution: the episode stage, the Dask build, the closed loop, the CLI."""


def __getattr__(name: str):
    # Lazy, so that importing the package stays light: ``pipeline.episode(spec)`` loads
    # the episode stage on first use (the submodule is itself callable).
    if name == "episode":
        import importlib

        return importlib.import_module("pipeline.episode")
    raise AttributeError(f"module 'pipeline' has no attribute {name!r}")
