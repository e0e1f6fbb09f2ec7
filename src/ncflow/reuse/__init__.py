"""Reusing a result of ``ncflow match``: an offline web viewer (:mod:`~ncflow.reuse.view`), source
attributes carried to the target through the correspondence (:mod:`~ncflow.reuse.transfer`) and
the target as a skinned glTF character (:mod:`~ncflow.reuse.rig`).
"""
