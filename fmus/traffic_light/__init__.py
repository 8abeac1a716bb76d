"""TrafficLightController FMU: NEMA dual-ring controller, NTCIP 1202 preemption, RS-232 AB3418-like port."""
