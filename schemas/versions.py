"""Versions pinned into every artifact Dyana writes, and the dataset's release notes.

``DATASET_VERSION`` names what the recipe and the stages produce: any change that alters
a built shard's bytes for the same slice and seed bumps it and adds a release note.
It is part of every manifest's ``settings``, so it is covered by the slice hash.
"""

CODE_VERSION = "0.1.0"
SCHEMA_VERSION = "1.0.0"
DATASET_VERSION = "1.0.0"
FPS = 20

#: Newest first. What changed in the data, and why.
RELEASE_NOTES = {
    "1.0.0": (
        "First release: the nine {linear,circular,harmonic}-{fast,medium,slow} slices and "
        "test-1k reproducing the paper's Figure 4; pybullet TinyRenderer frames composited "
        "over a static plate; JPEG quality 90; ground truth with a ramp-cruise-ramp approach."
    ),
}
