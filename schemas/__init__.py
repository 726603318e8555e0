"""Dyana's data contract: validated frozen dataclasses, Arrow schemas, versions."""
