"""RSU application: camera ingest, vehicle perception, tracking and V2X broadcast.

Runs as its own process and never imports the master; it talks to the
world only through `bridges/` (see DESIGN.md, section 1).
"""
