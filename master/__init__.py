"""The co-simulation master: scenario files, the stepping loop, time modes, run folders, the `v2i` CLI."""

__version__ = "0.1.0"
