"""Physics of the accelerometer triad on a two-axis bench (no I/O)."""
