"""Versions pinned into every artifact Dyana writes."""

CODE_VERSION = "0.1.0"
SCHEMA_VERSION = "1.0.0"
FPS = 20
