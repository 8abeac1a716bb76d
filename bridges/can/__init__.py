"""CAN between the AV computer and the vehicle: the DBC (cav.dbc), its typed codec, and bus opening."""
