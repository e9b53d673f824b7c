"""What the engine hands out besides estimates: the posterior grid, the next goal, and the end-of-data survey
log and its solver."""
