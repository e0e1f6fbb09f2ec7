"""Reuse of compiled programs: the cache folder and JAX's persistent compilation cache in it
(:mod:`~ncflow.jit.cache`), size buckets that let arrays of similar size share a program
(:mod:`~ncflow.jit.buckets`) and compiling ahead in a background thread (:mod:`~ncflow.jit.ahead`).
"""
