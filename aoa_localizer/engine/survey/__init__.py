"""The survey model's side of the engine: the log of each channel's readings from stations that stood still, the
test of whether their stops show a site part, and where the end of data finds the survey model's solver."""
