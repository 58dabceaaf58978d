"""Reading and writing meshes (.off, .obj, .ply, .stl, .glb, .gltf) and correspondence files (.vts)."""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import numpy as np

from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh

logger = logging.getLogger(__name__)

MESH_SUFFIXES = (".off", ".obj", ".ply", ".stl", ".glb", ".gltf")
WRITABLE_SUFFIXES = (".off", ".obj", ".ply", ".stl", ".glb")
"""Mesh types :func:`save_mesh` writes (a .gltf would need its .bin beside it)."""


def load_mesh(path: str | os.PathLike, validate: bool = True) -> Mesh:
    """Read a triangle mesh without reordering or merging its vertices.

    Parameters
    ----------
    path : str or PathLike
        A ``.off``, ``.obj``, ``.ply``, ``.stl``, ``.glb`` or ``.gltf`` file (an STL's vertices
        are its facets' corners in file order, three per facet; a glTF scene's meshes are
        joined with their transforms applied, their vertices in order).
    validate : bool
        Run :func:`spidermatch.geometry.mesh.validate_mesh` (recommended).

    Returns
    -------
    Mesh
        ``verts`` (V, 3) float64 and ``faces`` (F, 3) int64 in file order.

    Raises
    ------
    MeshError
        The file is missing, has an unsupported type, cannot be parsed or fails validation.

    """
    path = Path(path)
    name = str(path)
    if path.is_dir():
        raise MeshError(f"{name}: is a folder, not a mesh file")
    if not path.is_file():
        raise MeshError(f"{name}: no such file")
    if path.suffix.lower() == ".gz":
        raise MeshError(GZIP_REFUSAL.format(path=name))
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(
            f"{name}: unsupported mesh type '{path.suffix}' (expected one of {', '.join(MESH_SUFFIXES)})"
        )
    if path.stat().st_size == 0:
        raise MeshError(f"{name}: empty mesh (the file is empty)")
    suffix = _content_suffix(path)
    readers = {".off": read_off, ".obj": read_obj}
    verts, faces, *notes = readers.get(suffix, _read_with_trimesh)(path)
    notes = tuple(notes[0]) if notes else ()
    if suffix != path.suffix.lower():
        notes = (f"{name}: holds an {suffix[1:].upper()} mesh, not what its name says; read as one", *notes)
    for note in notes:
        logger.warning("%s", note)
    if not validate:
        return Mesh(verts, faces, name, notes)
    try:
        return make_mesh(verts, faces, name, notes)
    except MeshError as error:
        from spidermatch.geometry.weld import soup_refusal, welded

        weld = welded(Mesh(verts, faces, name, notes))
        if weld is None:
            raise
        raise MeshError(soup_refusal(error, weld)) from None


GZIP_MAGIC = b"\x1f\x8b"
GZIP_REFUSAL = "{path}: gzip-compressed; decompress it first (gunzip, or Python's gzip module)"


def _content_suffix(path: Path) -> str:
    """The reader's suffix for ``path``: its own, or ``.off``/``.obj`` when it holds the other text format.

    Raises
    ------
    MeshError
        The file is gzip-compressed (a ``.off.gz`` renamed, a download not yet unpacked).
    """
    suffix = path.suffix.lower()
    with path.open("rb") as handle:
        head = handle.read(4096)
    if head.startswith(GZIP_MAGIC):
        raise MeshError(GZIP_REFUSAL.format(path=path))
    if suffix not in (".off", ".obj"):
        return suffix
    first = _first_token(head)
    if first is not None and OFF_KEYWORD.fullmatch(first):
        return ".off"
    if first in ("v", "vt", "vn", "f", "o", "g", "mtllib", "usemtl", "s"):
        return ".obj"
    return suffix


def _first_token(head: bytes) -> str | None:
    """The first token of the first line with content (``#`` starts a comment) in ``head``, or None."""
    text = head.decode("utf-8", errors="replace").removeprefix("\ufeff")
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if tokens:
            return tokens[0]
    return None


def _text_of(path: Path) -> str:
    """The file's text, or a MeshError naming it when it is not UTF-8 text."""
    try:
        return path.read_bytes().decode("utf-8").removeprefix("\ufeff")  # a byte-order mark is no content
    except UnicodeDecodeError as error:
        raise MeshError(f"{path}: not a text file (byte {error.start} is not UTF-8)") from error


def _content_lines(path: Path, text: str | None = None) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of each line with content; ``#`` starts a comment.

    ``text``: the file's text, if the caller has read it already.
    """
    text = _text_of(path) if text is None else text
    lines = []
    for number, line in enumerate(text.splitlines(), start=1):
        tokens = line.split("#", 1)[0].split()
        if tokens:
            lines.append((number, tokens))
    return lines


OFF_KEYWORD = re.compile(r"(ST)?C?N?OFF")
"""OFF header keywords in 3-D: ``OFF``, ``COFF`` (vertex colours), ``NOFF`` (normals), ``STOFF``, ..."""


def _off_counts(path: Path, lines: list[tuple[int, list[str]]]) -> tuple[int, int, int]:
    """Vertex and face counts from the header, and the index of the first data line."""
    if not lines or not OFF_KEYWORD.fullmatch(lines[0][1][0]):
        first = " ".join(lines[0][1])[:40] if lines else ""
        raise MeshError(
            f"{path}: not an OFF file (the first line must be 'OFF', or COFF, NOFF, ...; found {first!r})"
        )
    counts, start = lines[0][1][1:], 1
    if not counts:
        if len(lines) < 2:
            raise MeshError(f"{path}: the OFF header has no vertex and face counts")
        counts, start = lines[1][1], 2
    line = lines[start - 1][0]
    if len(counts) not in (2, 3) or not all(c.isascii() and c.isdigit() for c in counts):
        raise MeshError(
            f"{path}:{line}: expected the counts 'VERTICES FACES EDGES', got {' '.join(counts)!r}"
        )
    return int(counts[0]), int(counts[1]), start


def _off_block(path: Path, lines, dtype, width: int, what: str) -> np.ndarray:
    """The numbers of ``lines`` as an array (N, width), or a MeshError naming the first bad line."""
    for number, tokens in lines:
        if len(tokens) != width:
            raise MeshError(f"{path}:{number}: a {what} line needs {width} numbers, found {len(tokens)}")
    try:
        return np.array([tokens for _, tokens in lines], dtype=str).astype(dtype).reshape(-1, width)
    except (ValueError, OverflowError):
        for number, tokens in lines:
            try:
                np.array(tokens, dtype=str).astype(dtype)
            except (ValueError, OverflowError):
                raise MeshError(
                    f"{path}:{number}: {what} line holds a non-number: {' '.join(tokens)!r}"
                ) from None
        raise


def read_off(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read an OFF file strictly: the header's counts must match what the file holds.

    Vertex lines begin with three coordinates (colours or normals after them, as COFF and NOFF
    write them, are ignored), face lines with ``n i_1 ... i_n`` (a face colour after them is
    ignored; polygons are split into triangle fans, which the notes report); fewer lines than
    promised, or anything after the promised faces, is an error naming the file (and the line).

    Returns
    -------
    verts : np.ndarray, shape (V, 3), float64
    faces : np.ndarray, shape (F, 3), int64 (indices not yet range-checked)
    notes : list of str
        What was changed on reading (polygons split).

    """
    path = Path(path)
    text = _text_of(path)
    quick = _parse_plain_off(text)
    if quick is not None:
        return (*quick, [])
    lines = _content_lines(path, text)
    n_verts, n_faces, start = _off_counts(path, lines)
    body = lines[start:]
    if len(body) < n_verts + n_faces:
        held_verts = min(len(body), n_verts)
        raise MeshError(
            f"{path}: the header promises {n_verts} vertices and {n_faces} faces, but the file ends after "
            f"{held_verts} vertices and {max(len(body) - n_verts, 0)} faces (truncated?)"
        )
    if len(body) > n_verts + n_faces:
        number = body[n_verts + n_faces][0]
        raise MeshError(
            f"{path}:{number}: unexpected content after the {n_verts} vertices and {n_faces} faces the "
            "header promises"
        )
    verts = _off_block(
        path, [(number, tokens[:3]) for number, tokens in body[:n_verts]], np.float64, 3, "vertex"
    )
    faces, polygons = _off_faces(path, body[n_verts:])
    return verts, faces, _split_notes(path, polygons)


def _split_notes(path: Path, polygons: int) -> list[str]:
    """The reader's note on ``polygons`` faces of more than three corners split into triangles."""
    return (
        [f"{path}: {polygons} faces with more than three corners were split into triangles"]
        if polygons
        else []
    )


def _fan(corners) -> list[list]:
    """A polygon's corners (n >= 3) as the triangles of a fan from its first corner."""
    return [[corners[0], corners[k], corners[k + 1]] for k in range(1, len(corners) - 1)]


def _off_faces(path: Path, lines) -> tuple[np.ndarray, int]:
    """Triangles (F, 3) of OFF face lines ``n i_1 ... i_n [colour]``, and how many polygons were split.

    A polygon (n > 3) is split into a triangle fan (:func:`_fan`); the triangles' indices are
    converted in one block.
    """
    counts = _off_block(path, [(number, tokens[:1]) for number, tokens in lines], np.int64, 1, "face")[:, 0]
    for (number, tokens), corners in zip(lines, counts):
        if corners < 3 or len(tokens) < corners + 1:
            raise MeshError(
                f"{path}:{number}: a face line needs its corner count (at least 3) and that many indices, "
                f"found {' '.join(tokens)!r}"
            )
    triangles = _off_block(
        path, [(n, tokens[1:4]) for (n, tokens), c in zip(lines, counts) if c == 3], np.int64, 3, "face"
    )
    polygons = [
        _fan(_off_block(path, [(n, tokens[1 : c + 1])], np.int64, c, "face")[0])
        for (n, tokens), c in zip(lines, counts)
        if c > 3
    ]
    if not polygons:
        return triangles, 0
    rows, fans = iter(triangles), iter(polygons)  # each face's triangles back in file order
    in_order = [t for c in counts for t in ([next(rows)] if c == 3 else next(fans))]
    return np.array(in_order, dtype=np.int64).reshape(-1, 3), len(polygons)


def _parse_plain_off(text: str) -> tuple[np.ndarray, np.ndarray] | None:
    """A well-formed OFF text without comments or blank lines, parsed in bulk (None: anything else).

    Large scans are read in bulk instead of token by token, several times faster (measurements:
    bench/README.md, solver constants); every file this does not accept exactly,
    :func:`read_off` parses line by line, naming the first bad line.
    """
    if "#" in text:
        return None
    lines = text.split("\n", 2)
    header = lines[0].split()
    if header[:1] != ["OFF"] or len(lines) < 3:
        return None
    counts, rest = (header[1:], "\n".join(lines[1:])) if len(header) > 1 else (lines[1].split(), lines[2])
    if len(counts) not in (2, 3) or not all(c.isascii() and c.isdigit() for c in counts):
        return None
    n_verts, n_faces = int(counts[0]), int(counts[1])
    rows = rest.rstrip("\r\n").split("\n")
    if len(rows) != n_verts + n_faces:
        return None
    vertex_rows, face_rows = rows[:n_verts], rows[n_verts:]
    if any(len(row.split()) != 3 for row in vertex_rows) or any(len(row.split()) != 4 for row in face_rows):
        return None
    try:
        verts = np.array(" ".join(vertex_rows).split(), dtype=np.float64).reshape(n_verts, 3)
        faces = np.array(" ".join(face_rows).split(), dtype=np.int64).reshape(n_faces, 4)
    except (ValueError, OverflowError):
        return None
    if (faces[:, 0] != 3).any():
        return None
    return verts, faces[:, 1:]


def _obj_index(token: str, n_verts: int, path: Path, number: int) -> int:
    """0-based vertex index of an OBJ face corner ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``."""
    text = token.split("/", 1)[0]
    try:
        index = int(text)
    except ValueError:
        raise MeshError(f"{path}:{number}: face corner {token!r} is not a vertex index") from None
    if index == 0:
        raise MeshError(f"{path}:{number}: OBJ vertex indices start at 1, found 0")
    return index - 1 if index > 0 else n_verts + index  # negative: relative to the vertices so far


def read_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read the vertices and faces of an OBJ file, in file order, into one mesh.

    Only ``v`` and ``f`` lines count: groups and objects (``o``, ``g``), materials
    (``usemtl``, ``mtllib``), texture coordinates and normals, as Blender and most tools
    write them, are ignored; all faces index the one vertex pool. Polygons with more than
    three corners are split into triangle fans, which the returned notes report.

    Returns
    -------
    verts : np.ndarray, shape (V, 3), float64
    faces : np.ndarray, shape (F, 3), int64 (indices not yet range-checked)
    notes : list of str
        What was changed on reading (polygons split).

    """
    path = Path(path)
    verts, faces, polygons = [], [], 0
    for number, tokens in _content_lines(path):
        if tokens[0] == "v":
            if len(tokens) < 4:
                raise MeshError(
                    f"{path}:{number}: a vertex line needs 3 coordinates, found {len(tokens) - 1}"
                )
            try:
                verts.append([float(value) for value in tokens[1:4]])
            except ValueError:
                raise MeshError(
                    f"{path}:{number}: vertex line holds a non-number: {' '.join(tokens)!r}"
                ) from None
        elif tokens[0] == "f":
            corners = [_obj_index(token, len(verts), path, number) for token in tokens[1:]]
            if len(corners) < 3:
                raise MeshError(f"{path}:{number}: a face needs at least 3 corners, found {len(corners)}")
            polygons += len(corners) > 3
            faces += _fan(corners)
    notes = _split_notes(path, polygons)
    faces_array = np.array(faces, dtype=np.int64).reshape(-1, 3)
    return np.array(verts, dtype=np.float64).reshape(-1, 3), faces_array, notes


def _point_count(path: Path) -> int:
    """Points of a file trimesh reads as a point cloud (0 for anything else or an unreadable file)."""
    import trimesh

    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception:  # only for the message: the caller reports the file as unreadable
        return 0
    return len(loaded.vertices) if isinstance(loaded, trimesh.PointCloud) else 0


def _read_with_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        loaded = trimesh.load(
            str(path), process=False, maintain_order=True, force="mesh", skip_materials=True
        )
    except Exception as error:  # trimesh raises many unrelated types on bad files
        raise MeshError(f"{path}: could not be read as a mesh ({type(error).__name__}: {error})") from error
    verts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if faces.size == 0:
        points = verts.shape[0] or _point_count(path)  # force="mesh" drops a point cloud's points
        what = f"a point cloud of {points} points" if points else f"not a {path.suffix.lower()} file"
        raise MeshError(f"{path}: no triangles could be read ({what}?); spidermatch needs a triangle mesh")
    return verts, faces.reshape(-1, 3) if faces.size else np.zeros((0, 3), dtype=np.int64)


def save_mesh(mesh: Mesh, path: str | os.PathLike) -> None:
    """Write a mesh; the type follows the suffix (``WRITABLE_SUFFIXES``). Vertex order is kept."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in WRITABLE_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh type '{path.suffix}'")
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(mesh.verts, mesh.faces, process=False).export(str(path))


def read_vts(path: str | os.PathLike, n_verts: int | None = None) -> np.ndarray:
    """Read a ``.vts`` correspondence file (1-based vertex indices, one per line).

    Parameters
    ----------
    path : str or PathLike
    n_verts : int, optional
        Number of vertices of the mesh the file refers to; indices are checked against it.

    Returns
    -------
    np.ndarray, shape (K,), int64
        0-based vertex indices; row k of two shapes' files correspond.

    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: no such correspondence file")
    values = []
    for number, tokens in _content_lines(path):
        if len(tokens) > 1:
            raise MeshError(
                f"{path}:{number}: {len(tokens)} numbers on one line; a .vts file holds one vertex index "
                "per line"
            )
        for token in tokens:
            if not (
                token.isascii() and token.lstrip("+-").isdigit() and len(token) - len(token.lstrip("+-")) <= 1
            ):
                raise MeshError(f"{path}:{number}: {token!r} is not an integer vertex index")
            values.append(int(token))
    if not values:
        raise MeshError(f"{path}: empty correspondence file")
    if max(values) > np.iinfo(np.int64).max:
        raise MeshError(f"{path}: vertex index {max(values)} is out of range")
    one_based = np.array(values, dtype=np.int64)
    if one_based.min() < 1:
        raise MeshError(f"{path}: .vts indices are 1-based, found {int(one_based.min())}")
    if n_verts is not None and one_based.max() > n_verts:
        raise MeshError(f"{path}: index {int(one_based.max())} exceeds the mesh's {n_verts} vertices")
    return one_based - 1


def write_vts(indices: np.ndarray, path: str | os.PathLike) -> None:
    """Write 0-based vertex indices as a 1-based ``.vts`` file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.asarray(indices, dtype=np.int64) + 1, fmt="%d")
