"""V2X radio channel (802.11p/DSRC and LTE-V2X mode 4): the V2XChannel FMU and its model."""
