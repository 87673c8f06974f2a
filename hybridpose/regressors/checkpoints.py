"""Checkpoint files: atomic save, load with a clear error, the inference-only export, and the
checkpoints shipped in the package (``weights/``, how they were made: ``weights/README.md``).

Inference reads checkpoints through this module, never through the training code.
"""
from __future__ import annotations

from pathlib import Path

import torch

from ..io import atomic_write_with

# hybrid_config: the HybridConfig fields recommended for a hybrid using the network (hybridpose fit)
INFERENCE_KEYS = ("config", "model", "build", "dataset", "twins", "calibration", "epoch", "best", "hybrid_config")
# In last.pt only: what --resume needs to continue the run exactly.
RESUME_ONLY_KEYS = ("optimizer", "scheduler", "torch_rng", "loader_rng")
WEIGHTS_DIR = Path(__file__).parent / "weights"
# the regressor checkpoints in WEIGHTS_DIR (NAME.pt; twin_verifier.pt is not a regressor)
SHIPPED_REGRESSORS = ("default", "edge_on_expert")


def save_checkpoint(path: Path, payload: dict) -> None:
    """Atomic ``torch.save`` (temp file + rename): an interrupted write never corrupts a checkpoint."""
    atomic_write_with(path, lambda f: torch.save(payload, f))


def export_checkpoint(src, dst) -> dict:
    """Inference-only copy of a training checkpoint (no optimizer/RNG state; the best validation
    row kept as ``validation``), written atomically. Returns it."""
    ck = load_checkpoint(src)
    missing = [k for k in ("config", "model", "build") if k not in ck]
    if missing:
        raise ValueError(f"{src}: not a hybridpose training checkpoint (missing {', '.join(missing)})")
    out = {k: ck[k] for k in INFERENCE_KEYS if k in ck}
    history = ck.get("history") or []
    if history:
        out["validation"] = min(history, key=lambda r: r["val_loss"])
    save_checkpoint(Path(dst), out)
    return out


def load_checkpoint(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{path}: corrupt or truncated checkpoint ({exc})") from exc


def shipped_checkpoint(name: str = "default") -> Path:
    path = WEIGHTS_DIR / f"{name}.pt"
    if not path.is_file():
        raise FileNotFoundError(
            f"checkpoint: no trained {name!r} checkpoint ships with hybridpose ({path}); pass checkpoint=PATH "
            f"(train one with `hybridpose train --model {name} ...`)"
        )
    return path


def checkpoint_or_shipped(value) -> Path:
    """The checkpoint file ``value`` names: the path itself where that file exists, else the checkpoint
    shipped under that name (``"default"``, ``"edge_on_expert"``: what the command line's
    ``--checkpoint default`` means). Raises FileNotFoundError naming both where neither exists."""
    path = Path(value)
    if path.is_file():
        return path
    if str(value) in SHIPPED_REGRESSORS:
        return shipped_checkpoint(str(value))
    raise FileNotFoundError(f"{value}: checkpoint not found (no such file, and not the name of one shipped with "
                            f"hybridpose: {', '.join(SHIPPED_REGRESSORS)})")
