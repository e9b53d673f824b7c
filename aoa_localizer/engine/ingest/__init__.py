"""Records to points: a fix or a DF record checked, placed on the vehicle's track and bearing,
batched into observation points (intake.py is the door)."""
