"""What the bearings say: likelihoods, the receiver's noise and offset, the start searches and the global
checks, triangulation and the emitter model."""
