"""Generalised winding numbers against analytic solid angles (ncflow.geometry.winding)."""

import numpy as np
import trimesh

from ncflow.geometry.winding import signed_volume, winding_numbers


def test_one_triangle_sees_an_octant():
    """The triangle (e1, e2, e3) spans one octant seen from the origin: solid angle 4π/8, winding 1/8;
    wound the other way, −1/8.
    """
    tri = np.eye(3)[None]
    assert np.allclose(winding_numbers(np.zeros((1, 3)), tri), 1.0 / 8.0, atol=1e-12)
    assert np.allclose(winding_numbers(np.zeros((1, 3)), tri[:, ::-1]), -1.0 / 8.0, atol=1e-12)


def test_a_sphere_winds_once_around_its_inside_only():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radius = np.concatenate([rng.uniform(0.0, 0.9, 200), rng.uniform(1.1, 3.0, 200)])
    points = directions * radius[:, None]
    w = winding_numbers(points, v[f])
    assert np.allclose(w[:200], 1.0, atol=1e-9) and np.allclose(w[200:], 0.0, atol=1e-9)
    assert np.allclose(winding_numbers(points, v[f][:, ::-1]), -w, atol=1e-12)
    assert signed_volume(v, f) > 0
