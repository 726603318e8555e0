"""The store: shard writers and readers, manifests, hashes, verify, the dataloader.

``catalog.open(path, ...)`` opens built slices or rollouts for training
(``catalog.loader.opening.open_dataset``); it is imported on first use, so importing
``catalog`` stays light.
"""


def __getattr__(name: str):
    if name == "open":
        from catalog.loader.opening import open_dataset  # lazy: numpy, pyarrow, cv2 load on first use

        return open_dataset
    raise AttributeError(f"module 'catalog' has no attribute {name!r}")
