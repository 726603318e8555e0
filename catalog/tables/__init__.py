"""The shard formats: Parquet tables and MCAP files written and read, the JPEG pages inside
Parquet, integrity checks and normalisation statistics.
"""
