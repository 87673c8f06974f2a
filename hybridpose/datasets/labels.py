"""The paper's ``labels.csv``: ``image, tx, ty, tz, qw, qx, qy, qz`` (metres, unit quaternion)."""
from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import Pose
from ..geometry.checks import QUAT_NORM_ATOL
from ..io import atomic_write_text

HEADER = ["image", "tx", "ty", "tz", "qw", "qx", "qy", "qz"]


@dataclass(frozen=True)
class Label:
    image: str  # path relative to the dataset root
    pose: Pose


def write_labels(path, labels: list[Label]) -> None:
    """Write ``labels.csv`` atomically; quaternions canonical (w ≥ 0), 9 decimals."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(HEADER)
    for lab in labels:
        q, t = lab.pose.quat_wxyz, lab.pose.t
        w.writerow([lab.image, *(f"{x:.9f}" for x in (*t, *q))])
    atomic_write_text(path, buf.getvalue())


def read_labels(path) -> list[Label]:
    """Read ``labels.csv``; errors name the file and the row.

    Raises:
        FileNotFoundError: missing file. ValueError: wrong header, non-numeric values, non-unit
        quaternion (‖q‖ off by more than 1e-4) or an empty file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: labels file not found")
    rows = list(csv.reader(path.read_text().splitlines()))
    if not rows or [c.strip() for c in rows[0]] != HEADER:
        raise ValueError(f"{path}: expected header {','.join(HEADER)}, got {','.join(rows[0]) if rows else 'an empty file'}")
    out = []
    for n, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != len(HEADER):
            raise ValueError(f"{path} line {n}: expected {len(HEADER)} columns, got {len(row)}")
        try:
            vals = np.array([float(x) for x in row[1:]])
        except ValueError:
            raise ValueError(f"{path} line {n}: non-numeric value in {row[1:]}") from None
        norm = np.linalg.norm(vals[3:])
        if abs(norm - 1.0) > QUAT_NORM_ATOL:
            raise ValueError(f"{path} line {n}: quaternion (qw, qx, qy, qz) has norm {norm:.6f}, expected 1")
        out.append(Label(row[0], Pose.from_quat_t(vals[3:], vals[:3])))
    if not out:
        raise ValueError(f"{path}: no labels (empty dataset)")
    return out
