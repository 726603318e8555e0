"""The episode stage chain: a spec -> per-frame states and actions -> rendered, encoded frames."""
