"""The project's FMUs: plain-Python models wrapped by thin pythonfmu slaves.

Each subfolder holds one FMU: `model.py` (the model, testable without FMI)
and `slave.py` (the `Fmi2Slave` wrapper). `fmus.builder` turns them into
validated `.fmu` files.
"""
