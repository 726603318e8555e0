"""The store: shard writers and readers, manifests, hashes, verify, the dataloader."""
