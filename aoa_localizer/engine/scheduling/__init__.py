"""When work is done: the scheduler of deferred jobs, its time slices and cost meter, the memory settings
and the worker's parent-death guard."""
