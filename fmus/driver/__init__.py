"""SignalDriver FMU: a human driver who stops for red and yellow at a signalised approach."""
