"""What a finished run looks like to a person: `v2i report` (one HTML page per run) and `v2i snapshot`.

`page` writes the self-contained HTML page from what the run folder recorded, `cli` is its command,
`snapshot` renders the world at one simulated time. It reads run folders through `master.run`'s
records and metrics; nothing of the loop, the links or the scenario reader imports it
(tests/test_boundaries.py).
"""
