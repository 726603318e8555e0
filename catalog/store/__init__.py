"""Where a folder's files live and what describes them: atomic writes, storage locations, hashes,
shard records, the manifest (``catalog.json``) and what it says.
"""
