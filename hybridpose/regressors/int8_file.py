"""The 8-bit model file of a keypoint checkpoint: where it lives, the record it carries, whether it
still belongs to its checkpoint. Read by the inference engines; written by
:mod:`hybridpose.training.quantize` (the job that makes it imports the regressor, so the format
lives apart and the engines never import the job).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

META_KEY = "hybridpose"  # the ONNX metadata key of the record (checkpoint hash, crops, calibration data)


def int8_path(checkpoint) -> Path:
    """Where the 8-bit model of ``checkpoint`` lives by default: beside it, ``NAME.int8.onnx``."""
    checkpoint = Path(checkpoint)
    return checkpoint.with_name(checkpoint.stem + ".int8.onnx")


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_record(path) -> dict:
    """The record :func:`quantize_checkpoint` stored in an 8-bit model file (ValueError naming the file
    when it is not one)."""
    import onnx

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 — whatever onnx raises on a corrupt file
        raise ValueError(f"{path}: not an ONNX model ({exc})") from exc
    meta = {p.key: p.value for p in model.metadata_props}
    if META_KEY not in meta:
        raise ValueError(f"{path}: not made by hybridpose quantize (no {META_KEY!r} record)")
    return json.loads(meta[META_KEY])


def stale_int8(checkpoint) -> Path | None:
    """The 8-bit model file beside ``checkpoint`` (:func:`int8_path`) when it was not made from this very
    file (retrained or re-calibrated since, or unreadable), else None (none there, or up to date)."""
    path = int8_path(checkpoint)
    if not path.is_file():
        return None
    try:  # load_int8's own checks (readable, made from this checkpoint), so the two cannot disagree
        load_int8(checkpoint, path)
    except ValueError:
        return path
    return None


def load_int8(checkpoint, path=None) -> tuple[bytes, dict]:
    """The 8-bit model of ``checkpoint`` (bytes) and its record; ValueError naming the file when it is
    missing or was made from another checkpoint."""
    path = int8_path(checkpoint) if path is None else Path(path)
    if not path.is_file():
        raise ValueError(f"engine='onnxruntime-int8': no 8-bit model {path} for {checkpoint} (make it with "
                         f"hybridpose quantize --checkpoint {checkpoint} --data DIR)")
    record = read_record(path)
    if record.get("checkpoint_sha256") != file_sha256(checkpoint):
        raise ValueError(f"engine='onnxruntime-int8': {path} was quantized from another {record.get('checkpoint')} "
                         f"than {checkpoint}; run hybridpose quantize again")
    return path.read_bytes(), record
