"""Pure NumPy geometry: meshes, topology, normalisation, closest points, winding numbers, rigid maths, remeshing.

No files and no JAX: the bottom layer that every other package of ncflow builds on
(docs/architecture.md, "Layers and the import rule").
"""
