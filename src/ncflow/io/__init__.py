"""Everything that crosses the file boundary: meshes, skeletons, glTF, MANO, ground truth, the result contract,
attribute files (vertex arrays, OBJ UVs, PLY properties, landmarks) and the rigged-character writer.

Readers validate what they read and turn every problem into one :class:`~ncflow.errors.InputError`
line naming the file; writers check their arrays first, so nothing non-finite or inconsistent is
written (docs/architecture.md, "Layers and the import rule": ``io`` uses only ``geometry``).
"""
