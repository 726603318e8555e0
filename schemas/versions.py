"""Versions pinned into every artifact Dyana writes, and the dataset's release notes.

``DATASET_VERSION`` names what the recipe and the stages produce: any change that alters
a built shard's bytes for the same slice and seed bumps it and adds a release note.
It is part of every manifest's ``settings``, so it is covered by the slice hash.
"""

CODE_VERSION = "0.1.0"
SCHEMA_VERSION = "1.0.0"
DATASET_VERSION = "3.0.0"
#: Dataset versions whose folders this code still reads (and ``catalog migrate`` moves into the
#: 3.0.0 folder layout); only the current one is rebuilt byte for byte.
READABLE_DATASET_VERSIONS = ("2.0.0", "3.0.0")
FPS = 20

#: Newest first. What changed in the data, and why.
RELEASE_NOTES = {
    "3.0.0": (
        "Storage only: each table has a folder of its own (frames/, episodes/, mcap/ instead of "
        "all three in shards/), so pandas, pyarrow.dataset and DuckDB open a table folder as one "
        "dataset; settings record the stored formats (MCAP can be left out); MCAP episodes play "
        "back to back with per-episode metadata records and the hand's frames; Parquet files "
        "carry a page index and ~40 kB data pages (a remote reader fetches one page per image). Frames and "
        "episodes tables hold the same rows and values as 2.0.0. `catalog migrate DIR` moves a "
        "2.0.0 folder into the new layout without rewriting its files."
    ),
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
