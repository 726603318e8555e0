"""Versions pinned into every artifact Dyana writes; their release notes are CHANGELOG.md.

``CODE_VERSION`` is the package's version (pyproject.toml reads it from here) and must
equal CHANGELOG.md's newest released heading (tests/docs checks). It is written into
every MCAP file, so changing it changes the built bytes and the slice hash.
``DATASET_VERSION`` names what the recipe and the stages produce: any change that alters
a built shard's bytes for the same slice and seed bumps it and adds a changelog entry.
It is part of every manifest's ``settings``, so it is covered by the slice hash.
A build chooses its renderer (:mod:`schemas.renderers`), and the renderer decides the
version: ``window`` writes ``DATASET_VERSION`` (5.0.0: the opposed-thumb hand with the
wrist reflex; 4.0.0 and 3.0.0, the splayed hand, are built by commit ebf6e48).
"""

CODE_VERSION = "0.1.0"
SCHEMA_VERSION = "1.0.0"
DATASET_VERSION = "5.0.0"
#: Dataset versions whose folders this code still reads (and ``catalog migrate`` moves into the
#: folder layout of 3.0.0 and later).
READABLE_DATASET_VERSIONS = ("2.0.0", "3.0.0", "4.0.0", "5.0.0")
FPS = 20
#: The closed loop's hand: a run records it (``settings.hand_model``). ``body-1``: a pybullet
#: body with speed, acceleration and joint limits that enters neither the table nor an
#: obstacle (:mod:`generators.hand_body`, issue 38). Runs recorded before it have no
#: ``hand_model`` (the hand was a pose the policy wrote): they are read and scored, and
#: re-executed byte for byte by :data:`POSE_HAND_COMMIT`'s code.
HAND_MODEL = "body-1"
#: The last commit whose closed loop has the pose hand (runs without ``hand_model``).
POSE_HAND_COMMIT = "84c8d50"
