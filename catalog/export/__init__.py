"""Exports of Dyana folders to other training stacks' formats (LeRobot v3.0 and v2.1)."""
