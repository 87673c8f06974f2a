"""ViSP's CAD format (``.cao``, version ``V1``), read at the edge into a triangle mesh.

A ``.cao`` file lists, each section a count then one row per item: 3D points (x y z, the file's
units), 3D lines (two point indices), faces from lines (n, then n line indices), faces from points
(n, then n point indices), cylinders and circles; ``#`` starts a comment, ``load("other.cao")``
merges another file (relative to this one), placed as ViSP places it where the call gives
``t=[x; y; z]`` (the file's units) and ``tu=[θu_x; θu_y; θu_z]`` (a rotation vector, each value in
radians or followed by ``deg``): a point ``p`` of the loaded file lands at ``R(θu)·p + t`` (nested
loads compose), and a row may end in ``name=…``-style attributes. What
ViSP's tracker follows are the faces' outlines; here the faces become triangles (ear clipping, any
simple planar polygon) and the trackers take the mesh's sharp edges.
Lines that bound no face, cylinders and circles have no surface to render or to hide edges behind:
a file with cylinders or circles is refused (mesh the part instead); loose lines are ignored.

No library reads ``.cao`` (trimesh, Open3D and meshio do not), hence this reader.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

_LOAD = re.compile(r'^load\("([^"]+)"((?:,\w+=\[[^\]]*\])*)\)$')  # spaces removed first
_LOAD_ARGUMENT = re.compile(r',(\w+)=\[([^\]]*)\]')
_ATTRIBUTE = re.compile(r'\w+\s*=\s*("[^"]*"|\S+)')  # name="…", useLod=true, minLineLengthThreshold=…


def _indices(tokens: list[str]) -> list[int]:
    """A face row: its count n, then n indices."""
    n = int(tokens[0])
    if len(tokens) < 1 + n:
        raise ValueError("fewer indices than the count")
    return [int(x) for x in tokens[1:1 + n]]


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of the file's non-empty lines, comments and ``key=value`` attributes dropped."""
    rows = []
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if text:
            rows.append((number, [text] if text.startswith("load(") else _ATTRIBUTE.sub(" ", text).split()))
    return rows


def _read(path: Path, depth: int = 0) -> tuple[np.ndarray, list[list[int]]]:
    """Points (N, 3) float64 and faces (lists of point indices) of ``path`` and the files it loads."""
    if depth > 16:
        raise ValueError(f"{path}: load(...) nests deeper than 16 files (a file that loads itself?)")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: .cao file not found")
    rows = _rows(path)
    points, faces = [], []
    i = 0
    if i < len(rows) and rows[i][1] == ["V1"]:
        i += 1
    while i < len(rows) and rows[i][1][0].startswith("load("):
        number, (text,) = rows[i]
        match = _LOAD.match(text.replace(" ", "").replace("\t", ""))
        if match is None:
            raise ValueError(f"{path}:{number}: expected load(\"file.cao\") or load(\"file.cao\", t=[x; y; z], "
                             f"tu=[θu_x; θu_y; θu_z]), got {text!r}")
        R, t = _placement(match.group(2), f"{path}:{number}")
        sub_points, sub_faces = _read(path.parent / match.group(1), depth + 1)
        sub_points = sub_points @ R.T + t
        offset = sum(len(p) for p in points)
        points.append(sub_points)
        faces += [[k + offset for k in f] for f in sub_faces]
        i += 1

    if points and i == len(rows):  # an assembly: loads alone, nothing of its own
        return np.vstack(points), faces

    def count(what: str) -> int:
        nonlocal i
        if i >= len(rows):
            raise ValueError(f"{path}: ends before the number of {what}")
        number, tokens = rows[i]
        if len(tokens) != 1 or not tokens[0].isdigit():
            raise ValueError(f"{path}:{number}: expected the number of {what}, got {' '.join(tokens)!r}")
        i += 1
        return int(tokens[0])

    def items(what: str, parse) -> list:
        nonlocal i
        out = []
        for _ in range(count(what)):
            if i >= len(rows):
                raise ValueError(f"{path}: ends inside the {what}")
            number, tokens = rows[i]
            try:
                out.append(parse(tokens))
            except (ValueError, IndexError):
                raise ValueError(f"{path}:{number}: cannot read this row of {what}: {' '.join(tokens)!r}") from None
            i += 1
        return out

    base = sum(len(p) for p in points)
    own = np.array(items("3D points", lambda t: [float(t[0]), float(t[1]), float(t[2])]), float).reshape(-1, 3)
    lines = items("3D lines", lambda t: (int(t[0]), int(t[1])))
    line_faces = items("faces from lines", _indices)
    point_faces = items("faces from points", _indices)
    if i < len(rows) and (count("cylinders") or (i < len(rows) and count("circles"))):
        raise ValueError(f"{path}: cylinders and circles are not supported (no surface to render); "
                         "export the part as a mesh (.obj, .ply, .stl) instead")
    for face in line_faces:
        if any(not 0 <= k < len(lines) for k in face):
            raise ValueError(f"{path}: a face names a 3D line that does not exist (there are {len(lines)})")
        point_faces.append(_chain([lines[k] for k in face], path))
    for face in point_faces:
        if len(face) < 3 or any(not 0 <= k < len(own) for k in face):
            raise ValueError(f"{path}: a face needs ≥ 3 existing points (there are {len(own)}), got {face}")
    points.append(own)
    faces += [[k + base for k in f] for f in point_faces]
    return (np.vstack(points) if points else np.zeros((0, 3))), faces


def _placement(arguments: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) of a ``load`` call's ``,t=[…],tu=[…]`` (spaces removed; identity where absent)."""
    from ..geometry import rotvec_to_matrix

    values = {"t": np.zeros(3), "tu": np.zeros(3)}
    for key, body in _LOAD_ARGUMENT.findall(arguments):
        if key not in values:
            raise ValueError(f"{where}: load(...) takes t=[x; y; z] and tu=[θu_x; θu_y; θu_z], got {key}=[{body}]")
        parts = body.split(";")
        try:
            if len(parts) != 3:
                raise ValueError
            values[key] = np.array([_angle(v) if key == "tu" else float(v) for v in parts])
        except ValueError:
            unit = " (radians, or followed by deg)" if key == "tu" else ""
            raise ValueError(f"{where}: {key}=[{body}]: expected three numbers separated by ';'{unit}") from None
    return rotvec_to_matrix(values["tu"]), values["t"]


def _angle(text: str) -> float:
    """A ``tu`` value: radians, or degrees where it ends in ``deg`` (``rad`` also accepted)."""
    if text.endswith("deg"):
        return float(np.radians(float(text[:-3])))
    return float(text[:-3] if text.endswith("rad") else text)


def _chain(lines: list[tuple[int, int]], path: Path) -> list[int]:
    """The point loop a face's lines trace (each line shares a point with the next)."""
    loop = list(lines[0])
    rest = list(lines[1:])
    while rest:
        for j, (a, b) in enumerate(rest):
            if a == loop[-1] or b == loop[-1]:
                loop.append(b if a == loop[-1] else a)
                rest.pop(j)
                break
        else:
            raise ValueError(f"{path}: the lines of a face do not form a closed loop: {lines}")
    if loop[-1] != loop[0]:
        raise ValueError(f"{path}: the lines of a face do not form a closed loop: {lines}")
    return loop[:-1]


def _triangulate(points: np.ndarray, face: list[int], path: Path) -> list[list[int]]:
    """Triangles of a planar polygon ``face`` (point indices, either winding) wound as the polygon is:
    ear clipping in the polygon's plane (trimesh's own triangulation needs shapely and an earcut
    package; ViSP's faces have a few corners, so O(n³) is nothing)."""
    p = points[face]
    normal = np.zeros(3)
    for a, b in zip(p, np.roll(p, -1, axis=0)):  # Newell's normal: the polygon's, for any planar polygon
        normal += np.cross(a, b)
    if np.linalg.norm(normal) == 0:
        raise ValueError(f"{path}: face {face} has no area")
    u = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 * np.linalg.norm(normal) else [0, 1.0, 0])
    v = np.cross(normal, u)
    xy = np.stack([p @ u, p @ v], 1)  # counter-clockwise seen from the normal's side

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    left, out = list(range(len(face))), []
    while len(left) > 3:
        for j in range(len(left)):
            i0, i1, i2 = left[j - 1], left[j], left[(j + 1) % len(left)]
            a, b, c = xy[i0], xy[i1], xy[i2]
            if cross(a, b, c) <= 0:
                continue  # a reflex (or flat) corner is no ear
            if any(cross(a, b, xy[k]) >= 0 and cross(b, c, xy[k]) >= 0 and cross(c, a, xy[k]) >= 0
                   for k in left if k not in (i0, i1, i2)):
                continue  # another corner inside: cutting it off would cross the outline
            out.append([face[i0], face[i1], face[i2]])
            left.pop(j)
            break
        else:
            raise ValueError(f"{path}: face {face} is not a simple polygon (its outline crosses itself)")
    out.append([face[k] for k in left])
    return out


def read_cao(path):
    """The triangle mesh (trimesh.Trimesh, the file's units) of a ViSP ``.cao`` model's faces.

    Raises:
        FileNotFoundError: the file, or a file it loads, is missing.
        ValueError: a malformed row (naming file and line), cylinders or circles, a face that is no
            simple polygon, or no face at all.
    """
    import trimesh

    path = Path(path)
    points, faces = _read(path)
    if not faces:
        raise ValueError(f"{path}: no faces (faces from points or lines); the trackers need the part's surface")
    triangles = [t for f in faces for t in _triangulate(points, f, path)]
    mesh = trimesh.Trimesh(points, np.asarray(triangles), process=True)
    if mesh.is_watertight and mesh.volume < 0:  # faces wound clockwise seen from outside
        mesh.invert()
    return mesh
