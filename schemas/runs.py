"""What makes a Dyana folder a run (a policy's rollouts) and not a built slice: it names its
policy, in its manifest (``catalog.json``'s ``policy`` key, :attr:`Manifest.extra
<catalog.store.manifest.Manifest.extra>`) and in its episodes tables (the ``policy`` column of
:data:`schemas.tables.ROLLOUT_FIELDS`). :func:`is_run` is the one test, for both."""

from __future__ import annotations

from collections.abc import Collection

#: The manifest key and episodes column that a run has and a built slice has not.
RUN_KEY = "policy"


def is_run(keys: Collection[str]) -> bool:
    """Whether a folder's manifest keys (e.g. ``manifest.extra``) or an episodes table's
    column names are a run's."""
    return RUN_KEY in keys
