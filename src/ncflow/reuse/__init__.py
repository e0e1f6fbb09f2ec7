"""Reusing a result of ``ncflow match``: an offline web viewer (:func:`write_view`), source
attributes carried to the target through the correspondence (:func:`transfer`,
:func:`transfer_skin_weights`) and the target as a skinned glTF character (:func:`rig_result`).
"""

from ncflow.reuse.rig import rig_result
from ncflow.reuse.transfer import transfer
from ncflow.reuse.view import write_view
from ncflow.reuse.weights import transfer_skin_weights

__all__ = ["rig_result", "transfer", "transfer_skin_weights", "write_view"]
