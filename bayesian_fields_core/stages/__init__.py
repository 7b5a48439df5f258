"""The three pipeline stages; each reads and writes named artifacts through a `Store`."""
