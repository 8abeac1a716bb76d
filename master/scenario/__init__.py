"""Scenario files: reading a scenario (TOML, or an SSP 1.0 package) and checking it before anything runs.

This room owns the file formats and their checks: `loader` loads, resolves FMUs and validates; `tables`
reads one table value by value with `key: reason` errors; `overrides` applies `--set KEY=VALUE`;
`sections` says which module reads each top-level table; `conditions`, `scenario_events`, `input_file`
and `pki` read their sections (and provide the hook that acts on them during a run); `ssp`,
`ssp_import`, `ssp_export` and `ssp_cli` carry the scenario's FMU system to and from SSP. It imports
only the FMI layer (`master.fmi`) and the shared modules beside it (`errors`, `hooks`); it never
imports the stepping loop, the links, sweeps or the report (tests/test_boundaries.py).
"""
