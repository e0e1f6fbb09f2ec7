"""glTF 2.0 / GLB: reading skinned, animated characters, and writing the morph-target animation.

:mod:`~ncflow.io.gltf.document` decodes a file (buffers, accessors, nodes),
:mod:`~ncflow.io.gltf.animation` samples its animation clips, :mod:`~ncflow.io.gltf.skins` reads a
skin and poses its mesh, and :mod:`~ncflow.io.gltf.writer` writes ``animation.glb``.
"""
