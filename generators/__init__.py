"""Seeded, pure stages: motion, objects, hand, interception, scene and recipe."""
