"""Design studies through the twin: design sweeps, tolerance Monte Carlo, sensitivity, propagation."""
