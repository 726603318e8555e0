"""Policies for the closed loop."""
