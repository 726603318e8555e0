"""Versions pinned into every artifact Dyana writes, and the dataset's release notes.

``DATASET_VERSION`` names what the recipe and the stages produce: any change that alters
a built shard's bytes for the same slice and seed bumps it and adds a release note.
It is part of every manifest's ``settings``, so it is covered by the slice hash.
"""

CODE_VERSION = "0.1.0"
SCHEMA_VERSION = "1.0.0"
DATASET_VERSION = "2.0.0"
FPS = 20

#: Newest first. What changed in the data, and why.
RELEASE_NOTES = {
    "2.0.0": (
        "The resting hand moved from above the workspace (palm at y 3, z 0.5, where it hid the "
        "object in some observe frames) to the bottom edge of the view (y 1.65, z -1.8, fingers "
        "in view), so every recipe object is wholly unhidden while observed; the recipe's "
        "feasibility filter and every spec check the observe frames' visibility. Every "
        "episode's choices (object, motion, windows; Figure 4) are unchanged; the hand's "
        "approach, actions and frames differ. Results on 1.x and 2.x are not comparable."
    ),
    "1.0.0": (
        "First release: the nine {linear,circular,harmonic}-{fast,medium,slow} slices and "
        "test-1k reproducing the paper's Figure 4; pybullet TinyRenderer frames composited "
        "over a static plate; JPEG quality 90; ground truth with a ramp-cruise-ramp approach."
    ),
}
