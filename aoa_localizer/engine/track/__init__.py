"""The life of one emitter's estimate: collecting a window, starting, tracking, checking, calibrating,
and what it reports (emitter_track.py holds the track)."""
