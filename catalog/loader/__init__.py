"""The researchers' dataloader: ``catalog.open`` over built slices or rollouts, its index, filters,
windows, caches, streams and torch adapters.
"""
