"""`v2i sweep`: many full runs of one scenario, varied along axes, and one table of their metrics.

`spec` reads sweep files and makes the points, `point` runs one point as a full `v2i run` in its own
folder, `engines` chooses where points run (an existing scheduler, by name), `table` keeps the points'
record and table, `plots` and `dse` draw and tabulate them, `runner` is the command that ties them.
A sweep sits above a run: it reads scenarios and run metrics, and nothing of the loop imports it
(tests/test_boundaries.py).
"""
