"""The whole cell on a simulated clock, in one process: for sweeps faster than real time."""
