"""Sharded jobs and what runs over their folders: the runner, build, eval, replay, verify, view."""
