"""Sequences: one source with its skeleton registered to every frame of a capture (``ncflow track``).

:func:`track_sequence` (in :mod:`ncflow.track.sequence`) matches the first frame in full and every later
frame from the previous one (:mod:`ncflow.track.warm`), each anchored to the source; the frames are listed
by :mod:`ncflow.track.frames`; the animation of the whole (GLB with skin, exact per-frame corrections and
BVH) is made by :mod:`ncflow.track.animation` and :mod:`ncflow.track.outputs`.
"""

from ncflow.track.frames import frame_files
from ncflow.track.sequence import TrackReport, track_sequence

__all__ = ["TrackReport", "frame_files", "track_sequence"]
