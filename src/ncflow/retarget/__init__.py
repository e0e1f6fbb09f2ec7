"""A result carried to what users came for: source attributes on the target through the correspondence
(:func:`transfer`: per-vertex values, UVs, landmarks; :func:`transfer_skin_weights`) and the target as a
skinned glTF character (:func:`rig_result`).
"""

from ncflow.retarget.attributes import transfer
from ncflow.retarget.rig import rig_result
from ncflow.retarget.weights import transfer_skin_weights

__all__ = ["rig_result", "transfer", "transfer_skin_weights"]
