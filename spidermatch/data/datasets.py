"""Shape collections with ground truth: FAUST_r-style folders and generated creatures.

Both kinds share one API: ``names``, ``load(name) -> Shape``, ``pairs()``.
A FAUST_r-style folder holds ``off/NAME.off`` (or .obj/.ply) and
``corres/NAME.vts``: 1-based vertex indices of a shared set of reference points,
so row k of two shapes' files are corresponding vertices.
"""

from __future__ import annotations

import itertools
import logging
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from spidermatch.data.synthetic import fibonacci_sphere, make_creature
from spidermatch.geometry.io import MESH_SUFFIXES, load_mesh, read_vts, save_mesh, write_vts
from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh
from spidermatch.geometry.repair import Repair, largest_clean_piece
from spidermatch.geometry.weld import Weld, soup_refusal, welded

logger = logging.getLogger(__name__)


class DatasetError(ValueError):
    """A dataset folder or pairs file is unusable; the message names the path."""


@dataclass(frozen=True)
class Shape:
    """A mesh with the vertex index of each reference point.

    Attributes
    ----------
    name : str
    mesh : Mesh
    corr : np.ndarray, shape (K,), or None
        0-based vertex of each shared reference point, if ground truth is known.
    weld : Weld or None
        When the file was a triangle soup (an STL file, a vertex per corner) and ``mesh`` is
        it welded (:mod:`spidermatch.geometry.weld`): how the file's vertices lie in ``mesh``
        (``corr`` is already told in ``mesh``'s vertices).

    """

    name: str
    mesh: Mesh
    corr: np.ndarray | None = None
    weld: Weld | None = None


def all_ordered_pairs(names: list[str]) -> list[tuple[str, str]]:
    """Every (a, b) with a != b."""
    return [(a, b) for a, b in itertools.permutations(names, 2)]


def read_pairs_file(path: str | os.PathLike, names: list[str]) -> list[tuple[str, str]]:
    """Read ``source target`` name pairs (one per line, comma or white space; '#' comments)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such pairs file")
    known, pairs = set(names), []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.split("#", 1)[0].replace(",", " ").strip()
        if not line:
            continue
        pairs.append(checked_pair(line.split(), known, f"{path}:{number}"))
    return pairs


def checked_pair(fields: list[str], known: set[str], where: str) -> tuple[str, str]:
    """The (source, target) pair that ``fields`` names.

    Raises
    ------
    DatasetError
        Starting with ``where``, if ``fields`` are not two non-empty names or one is not in ``known``.

    """
    if len(fields) != 2 or not all(fields):
        raise DatasetError(f"{where}: expected two shape names, got {' '.join(fields)!r}")
    names = [_shape_name(field, known) for field in fields]
    missing = [field for field, name in zip(fields, names) if name not in known]
    if missing:
        raise DatasetError(f"{where}: unknown shape {missing[0]!r}")
    return names[0], names[1]


def _shape_name(field: str, known: set[str]) -> str:
    """``field`` as a shape name: a known name, or a mesh file name (``tr_reg_070.off``) of one."""
    path = Path(field)
    a_file_name = path.name == field and path.suffix.lower() in MESH_SUFFIXES  # no folder part
    return path.stem if field not in known and a_file_name and path.stem in known else field


def mesh_files(folder: Path) -> dict[str, Path]:
    """The mesh files of ``folder`` by name (file stem); DatasetError if two share a name."""
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower() not in MESH_SUFFIXES:
            continue
        if path.stem in files:
            raise DatasetError(f"{path}: two meshes are called {path.stem!r} ({files[path.stem].name})")
        files[path.stem] = path
    return files


class ShapeFolder:
    """Shapes in the FAUST_r layout (``off/`` meshes, ``corres/*.vts`` ground truth).

    The meshes may also lie in the folder itself (no ``off/``); ``corres/`` is optional.

    Parameters
    ----------
    root : str or PathLike
        The dataset folder.
    repair : bool
        A shape that fails the checks only as a raw scan does (debris, bow-ties, stray vertices,
        slivers) is loaded as its largest clean piece (:mod:`spidermatch.geometry.repair`), its
        reference points moved to the nearest vertex kept; otherwise it is refused.
    repair_option : str, optional
        The option that sets ``repair`` (``"data.repair=true"``), named in a refusal that the
        repair would mend.

    """

    def __init__(
        self, root: str | os.PathLike, repair: bool = False, repair_option: str | None = None
    ) -> None:
        self.root = Path(root)
        self.repair, self.repair_option = repair, repair_option
        self._repair_told: set[str] = set()  # shapes whose repair was logged (once each)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: no such folder")
        mesh_dir = self.root / "off" if (self.root / "off").is_dir() else self.root
        self._files = mesh_files(mesh_dir)
        if not self._files:
            raise DatasetError(
                f"{mesh_dir}: no mesh files ({'/'.join(MESH_SUFFIXES)}) found "
                "(looked in 'off/', else in the folder)"
            )
        self.names = sorted(self._files)

    def __len__(self) -> int:
        return len(self.names)

    def mesh_path(self, name: str) -> Path:
        """Path of the mesh file of shape ``name``."""
        if name not in self._files:
            raise DatasetError(f"{self.root}: no shape named {name!r}")
        return self._files[name]

    def corr_path(self, name: str) -> Path:
        """Path of the ground-truth file of shape ``name`` (it may not exist)."""
        return self.root / "corres" / f"{name}.vts"

    def load(self, name: str) -> Shape:
        """Load one shape and its ground truth (``corr`` is None if no .vts file exists)."""
        if name not in self._files:
            raise DatasetError(f"{self.root}: no shape named {name!r}")
        readable, weld, refusal = _mesh_or_welded(self._files[name])
        mesh, repaired = (readable, None) if refusal is None else self._repaired(readable, refusal)
        corr_file = self.corr_path(name)
        if not corr_file.is_file():
            return Shape(name, mesh, None, None if repaired else weld)
        corr = read_vts(corr_file, readable.n_verts if weld is None else weld.n_file)
        if weld is not None:
            corr = weld.to_welded[corr]
        if repaired is None:
            return Shape(name, mesh, corr, weld)
        return Shape(name, mesh, kept_reference_vertices(readable, repaired.piece.to_original, corr))

    def _repaired(self, readable: Mesh, refusal: MeshError) -> tuple[Mesh, Repair]:
        """The largest clean piece of ``readable`` and its repair (with ``repair``), else ``refusal``."""
        try:
            repaired = largest_clean_piece(readable)
        except MeshError:
            raise refusal from None
        if not self.repair:
            if self.repair_option is None:
                raise refusal
            raise MeshError(f"{refusal}; {self.repair_option} would use {repaired.summary}")
        if readable.name not in self._repair_told:  # once a shape, though checked before it is loaded
            self._repair_told.add(readable.name)
            option = self.repair_option or "the repair"
            logger.warning("%s: %s uses %s (as given: %s)", readable.name, option, repaired.summary, refusal)
        return repaired.piece.mesh, repaired

    def unusable(self, names: list[str]) -> list[str]:
        """What is wrong with each of the shapes ``names`` that cannot be loaded (messages name the files)."""
        problems = []
        for name in names:
            try:
                self.load(name)
            except (MeshError, DatasetError) as error:
                problems.append(str(error))
        return problems

    def pairs(self, pairs_file: str | os.PathLike | None = None) -> list[tuple[str, str]]:
        """Pairs from ``pairs_file`` or, without one, all ordered pairs."""
        return read_pairs_file(pairs_file, self.names) if pairs_file else all_ordered_pairs(self.names)


def _mesh_or_welded(path: Path) -> tuple[Mesh, Weld | None, MeshError | None]:
    """The mesh of ``path``, or, if it is no valid surface but welded would be, it welded.

    The file is read and welded once. Returns the mesh, its weld (or None) and None; or, for a
    mesh valid neither way, the mesh as read (welded, if it repeats vertices), its weld and the
    refusal: the error of the mesh as given (with the soup hint
    :func:`spidermatch.geometry.io.load_mesh` gives when it was welded).
    """
    given = load_mesh(path, validate=False)
    try:
        return make_mesh(given.verts, given.faces, given.name, given.notes), None, None
    except MeshError as error:
        weld = welded(given)
        if weld is None:
            return given, None, error
        try:
            mesh = make_mesh(weld.mesh.verts, weld.mesh.faces, weld.mesh.name, weld.mesh.notes)
        except MeshError:
            return weld.mesh, weld, MeshError(soup_refusal(error, weld))
        logger.warning("%s", weld.note)
        return mesh, weld, None


def kept_reference_vertices(mesh: Mesh, kept: np.ndarray, corr: np.ndarray) -> np.ndarray:
    """Reference vertices ``corr`` (K,) of ``mesh`` as vertices of its piece ``kept`` (V_piece,).

    A reference vertex the piece left out moves to the piece's vertex nearest to it in space
    (debris and bow-tie fans hold few of them).
    """
    from scipy.spatial import cKDTree

    position = np.full(mesh.n_verts, -1, dtype=np.int64)
    position[kept] = np.arange(kept.size)
    moved = position[corr]
    lost = np.flatnonzero(moved < 0)
    if lost.size:
        moved[lost] = cKDTree(mesh.verts[kept]).query(mesh.verts[corr[lost]])[1]
        logger.warning(
            "%s: %d reference points lay outside the piece kept; moved to its nearest vertex",
            mesh.name,
            lost.size,
        )
    return moved


class SyntheticShapes:
    """Generated creatures (see :mod:`spidermatch.data.synthetic`) with the ShapeFolder API.

    Parameters
    ----------
    n_shapes : int
    n_verts : int
        Approximate vertex count of each shape.
    seed : int
        Shape i uses seed ``seed + i``.
    n_refs : int
        Number of shared reference points for the ground truth.

    """

    def __init__(self, n_shapes: int = 6, n_verts: int = 2000, seed: int = 0, n_refs: int = 1000) -> None:
        if n_shapes < 1:
            raise DatasetError("SyntheticShapes needs n_shapes >= 1")
        self.n_verts, self.seed, self.n_refs = n_verts, seed, n_refs
        self.names = [f"creature_{seed + i:03d}" for i in range(n_shapes)]

    def __len__(self) -> int:
        return len(self.names)

    def load(self, name: str) -> Shape:
        """Generate (deterministically) the shape called ``name``."""
        if name not in self.names:
            raise DatasetError(f"synthetic dataset has no shape named {name!r}")
        return _synthetic_shape(name, int(name.rsplit("_", 1)[1]), self.n_verts, self.n_refs)

    def pairs(self, pairs_file: str | os.PathLike | None = None) -> list[tuple[str, str]]:
        """Pairs from ``pairs_file`` or all ordered pairs."""
        return read_pairs_file(pairs_file, self.names) if pairs_file else all_ordered_pairs(self.names)


@lru_cache(maxsize=32)
def _synthetic_shape(name: str, seed: int, n_verts: int, n_refs: int) -> Shape:
    creature = make_creature(n_verts, seed)
    mesh = Mesh(creature.mesh.verts, creature.mesh.faces, name)
    return Shape(name, mesh, creature.reference_vertices(fibonacci_sphere(n_refs)))


def write_dataset(shapes, root: str | os.PathLike, names: list[str] | None = None) -> Path:
    """Write shapes of any dataset to ``root`` in the FAUST_r layout (.off + .vts)."""
    root = Path(root)
    for name in names or shapes.names:
        shape = shapes.load(name)
        save_mesh(shape.mesh, root / "off" / f"{name}.off")
        if shape.corr is not None:
            write_vts(shape.corr, root / "corres" / f"{name}.vts")
    return root


def open_dataset(
    root: str | os.PathLike | None,
    repair: bool = False,
    repair_option: str | None = None,
    **synthetic_options,
) -> ShapeFolder | SyntheticShapes:
    """A ShapeFolder for ``root`` (see its ``repair``), or generated creatures for None or 'synthetic'."""
    if root in (None, "", "synthetic"):
        return SyntheticShapes(**synthetic_options)
    try:
        return ShapeFolder(root, repair, repair_option)
    except MeshError as error:  # pragma: no cover - ShapeFolder only lists files
        raise DatasetError(str(error)) from error
