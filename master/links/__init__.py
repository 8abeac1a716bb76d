"""What connects the stepping loop to the outside: apps, serial ports, CAN, the V2X air, sensor streams.

Each module is a hook of the loop (and the reader of its scenario section): `participants` (apps
following the master's clock over a bus), `serial_bridge` (an FMU's serial port as a socket),
`can_gateway` and `can_bridge` (the drive-by-wire CAN link), `radio_bridge` (the V2X air and its
channel model), `rsu_link` (real radios in the loop), `v2x_subject` (which vehicle a frame
describes), `streams` (camera, lidar and GNSS on the bus). Links know the scenario's tables and the
shared hook protocol, never the loop that runs them, sweeps or the report (tests/test_boundaries.py).
"""
