"""What the engine hands out: the estimates (the tracks fed the closed points), the views programs read (copied
values), the posterior grid, the next goal, and the end-of-data survey log and its solver."""
