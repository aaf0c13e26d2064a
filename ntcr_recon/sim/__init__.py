"""The synthetic rig: parametric NTCR, D405 depth emulation, bag writer."""
