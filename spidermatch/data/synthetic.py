"""Synthetic articulated creatures with exact ground-truth correspondence.

Every creature is the image of the unit sphere under a smooth, injective map:
a star-shaped rest surface (an ellipsoidal body with five limbs of different
lengths and directions, so that it has no symmetry) followed by a pose that
bends each limb about its joint. Each shape samples the sphere with its own
seeded point set, so two shapes have different vertex counts and connectivity;
a point of the sphere lands on corresponding surface points of every shape,
which gives exact ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from spidermatch.geometry.mesh import Mesh, make_mesh

BODY_RADII = np.array([1.3, 0.75, 0.6])


@dataclass(frozen=True)
class Limb:
    """A protrusion of the rest shape.

    Attributes
    ----------
    direction : np.ndarray, shape (3,)
        Unit direction from the centre.
    length : float
        How far the tip stands out from the body.
    angular_radius : float
        Half-width of the limb on the parameter sphere, radians.
    bend_axis : np.ndarray, shape (3,)
        Axis the limb bends about (unit, orthogonal to ``direction``).

    """

    direction: np.ndarray
    length: float
    angular_radius: float
    bend_axis: np.ndarray


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _limb(direction, length: float, radius: float, axis_hint) -> Limb:
    d = _unit(direction)
    axis = _unit(np.cross(d, _unit(axis_hint)))
    return Limb(d, length, radius, axis)


LIMBS = (
    _limb([1.0, 0.1, 0.55], 0.55, 0.42, [0, 0, 1]),  # head
    _limb([0.25, 1.0, 0.2], 1.05, 0.30, [0, 1, 0]),  # long arm
    _limb([0.35, -1.0, 0.1], 0.75, 0.33, [0, 1, 0]),  # short arm
    _limb([-0.3, 0.45, -1.0], 1.0, 0.32, [1, 0, 0]),  # leg
    _limb([-0.45, -0.5, -1.0], 1.2, 0.30, [1, 0, 0]),  # longer leg
    _limb([-1.0, 0.0, 0.3], 0.9, 0.22, [0, 0, 1]),  # tail
)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random proper rotation matrix (3, 3) (determinant +1)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def rotation_angle(matrix: np.ndarray) -> float:
    """Angle of a rotation matrix (3, 3), degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(matrix) - 1.0) / 2.0, -1.0, 1.0))))


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform points on the unit sphere, shape (n, 3)."""
    index = np.arange(n) + 0.5
    z = 1.0 - 2.0 * index / n
    theta = np.pi * (1.0 + 5**0.5) * index
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=1)


def sample_sphere(n: int, rng: np.random.Generator) -> np.ndarray:
    """A seeded, jittered Fibonacci point set on the unit sphere, shape (n, 3)."""
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    points = fibonacci_sphere(n) @ rotation.T
    points += rng.normal(scale=0.25 * np.sqrt(4 * np.pi / n), size=points.shape)
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def rest_surface(u: np.ndarray) -> np.ndarray:
    """Map sphere points (N, 3) to the rest creature (N, 3)."""
    body = 1.0 / np.sqrt(((u / BODY_RADII) ** 2).sum(axis=1))
    radius = body.copy()
    for limb in LIMBS:
        angle = np.arccos(np.clip(u @ limb.direction, -1.0, 1.0))
        radius += limb.length * _smoothstep((1.0 - angle / limb.angular_radius) / 0.55)
    return u * radius[:, None]


def _rotation(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotation matrices about one axis by N angles, shape (N, 3, 3) (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3)[None] + s * k[None] + (1.0 - c) * (k @ k)[None]


def posed_surface(u: np.ndarray, bend: np.ndarray) -> np.ndarray:
    """Map sphere points (N, 3) to the creature with limb k bent by ``bend[k]`` radians."""
    points = rest_surface(u)
    for limb, angle in zip(LIMBS, bend):
        base = 1.0 / np.sqrt(((limb.direction / BODY_RADII) ** 2).sum())
        joint = 0.95 * base * limb.direction
        along = (points - joint) @ limb.direction / limb.length
        on_limb = _smoothstep((u @ limb.direction - np.cos(1.4 * limb.angular_radius)) * 20.0)
        weight = _smoothstep(along / 0.45) * on_limb
        rotations = _rotation(limb.bend_axis, weight * angle)
        points = joint + np.einsum("nij,nj->ni", rotations, points - joint)
    return points


def sphere_triangulation(u: np.ndarray) -> np.ndarray:
    """Outward-oriented triangles of points on the unit sphere (convex hull), shape (F, 3)."""
    faces = ConvexHull(u).simplices.astype(np.int64)
    a, b, c = u[faces[:, 0]], u[faces[:, 1]], u[faces[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    faces[inward] = faces[inward][:, ::-1]
    return faces


@dataclass(frozen=True)
class SyntheticCreature:
    """One generated shape: its mesh and the sphere parameter of each vertex.

    Attributes
    ----------
    mesh : Mesh
    params : np.ndarray, shape (V, 3)
        Point of the unit sphere each vertex is the image of.

    """

    mesh: Mesh
    params: np.ndarray

    def reference_vertices(self, references: np.ndarray) -> np.ndarray:
        """Vertex nearest (on the parameter sphere) to each reference point, shape (K,)."""
        _, nearest = cKDTree(self.params).query(references)
        return np.asarray(nearest, dtype=np.int64)


def make_creature(n_verts: int = 2000, seed: int = 0, max_bend: float = 0.6) -> SyntheticCreature:
    """Generate a posed creature with about ``n_verts`` vertices.

    Parameters
    ----------
    n_verts : int
        Approximate vertex count (jittered by up to 5 % per seed).
    seed : int
        Selects the pose and the sampling (and hence the connectivity).
    max_bend : float
        Largest limb bend in radians.

    """
    rng = np.random.default_rng(seed)
    n = int(n_verts * rng.uniform(0.95, 1.05))
    u = sample_sphere(n, rng)
    bend = rng.uniform(-max_bend, max_bend, size=len(LIMBS))
    verts = posed_surface(u, bend)
    faces = sphere_triangulation(u)
    mesh = make_mesh(verts, faces, name=f"synthetic creature (seed {seed}, {n} vertices)")
    return SyntheticCreature(mesh, u)


def creature_pair_ground_truth(source: SyntheticCreature, target: SyntheticCreature) -> np.ndarray:
    """Dense ground truth: the target vertex nearest to each source vertex's parameter, (V_src,)."""
    _, nearest = cKDTree(target.params).query(source.params)
    return np.asarray(nearest, dtype=np.int64)


def centroid_split(verts: np.ndarray, faces: np.ndarray, chosen: np.ndarray) -> tuple:
    """The ``chosen`` faces (F,) bool each split into three at a new centroid vertex (appended).

    Needle triangles and vertices of high degree, as some exporters triangulate; the original
    vertices keep their indices (ground truth on them still holds).

    Returns the new vertices (V', 3), faces (F', 3) and which faces came from chosen ones (F',).
    """
    split = faces[chosen]
    centre = len(verts) + np.arange(len(split))
    a, b, c = split.T
    pieces = np.concatenate(
        [np.stack([a, b, centre], 1), np.stack([b, c, centre], 1), np.stack([c, a, centre], 1)]
    )
    new_faces = np.vstack([faces[~chosen], pieces])
    from_chosen = np.concatenate(
        [np.zeros(int((~chosen).sum()), dtype=bool), np.ones(len(pieces), dtype=bool)]
    )
    return np.vstack([verts, verts[split].mean(axis=1)]), new_faces, from_chosen
