"""8-bit keypoint networks for ONNX Runtime (``hybridpose quantize``; ``engine="onnxruntime-int8"``).

Static post-training quantization with ONNX Runtime's own tool (``onnxruntime.quantization``):
convolutions and residual sums in 8 bits (weights signed, per output channel, in 7 bits' range;
activations unsigned, per tensor, their ranges measured on calibration crops), the heatmap head, the twin head and the
soft-argmax left in float — a keypoint is the expectation over a softmax of the head's logits, and
8-bit logits would quantise it. The calibration crops are the ones ``predict`` feeds the network on
real views (first crop, turned crops, second pass), recorded on the float network; quantizing on
random or whole-image inputs would set the activation ranges for images the network never sees.

Weights in 7 bits' range (``reduce_range``) because x86 CPUs without VNNI multiply u8 × s8 pairs
with a 16-bit saturating sum (VPMADDUBSW), which full-range weights overflow: on 600 crops of test
seed 100 full range moved keypoints by 1.2 px (median; 9 px at the 90th percentile) from the float
network's and changed the twin head's choice on 6.7 % of them, 7 bits by 0.8 px (2.7 px) and 1.0 %.

The file records the SHA-256 of the checkpoint it was made from, and the regressor refuses a file
made from another one: the int8 weights would silently belong to an older network.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from ..io import atomic_write_bytes
from ..regressors.int8_file import META_KEY, file_sha256, int8_path, load_int8, read_record, stale_int8  # noqa: F401 (the format's names, used here and re-exported)

# left in float: the heatmap logits (a soft-argmax of 8-bit logits moves keypoints by up to a cell), the
# twin logits (one small matrix product, ≈ 0 of the time) and the first convolution (the image itself: in
# float it keeps the twin head closer to the float net's; docs/decisions.md)
FLOAT_NODES = ("/net/stem/stem.0/Conv", "/net/head/Conv", "/net/twin_head/Gemm")
QUANTIZED_OPS = ("Conv", "Add", "Relu")


def record_crops(reg, frames, limit: int, progress=None) -> np.ndarray:
    """The crops (M, 3, S, S) float32 in [0, 1] that ``reg.predict`` feeds its keypoint network on
    ``frames``, in order, at most ``limit`` (``progress(crops so far, limit)`` after each frame)."""
    engine, crops = reg.engine, []

    def recording(x):
        crops.extend(x.detach().cpu().numpy().astype(np.float32))
        return engine(x)

    reg.engine = recording
    try:
        for frame in frames:
            if len(crops) >= limit:
                break
            reg.predict(frame)
            if progress:
                progress(min(len(crops), limit), limit)
    finally:
        reg.engine = engine
    return np.stack(crops[:limit]) if crops else np.zeros((0, 3, reg.image_size, reg.image_size), np.float32)


def quantize_checkpoint(checkpoint, data, out=None, crops: int = 300, progress=None) -> dict:
    """Write the 8-bit ONNX model of a keypoint ``checkpoint`` (``out``, default :func:`int8_path`),
    calibrated on the crops the float network sees on the views of the BOP folder ``data`` (at most
    ``crops`` of them; ``progress(crops so far, crops)``). The file is written to a temporary name and renamed. Returns its record
    (path, checkpoint hash, crops, calibration data).

    Raises ValueError (naming the argument) for a direct (VGG) checkpoint, an empty ``data`` or
    ``crops`` < 1, and RuntimeError when onnxruntime is missing.
    """
    from ..core import Frame
    from ..datasets.bop import BopScene, find_scenes
    from ..regressors.predictor import CheckpointRegressor

    try:
        from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType,
                                              quantize_static)
        from onnxruntime.quantization.shape_inference import quant_pre_process
    except ImportError as exc:
        raise RuntimeError("hybridpose quantize needs the onnxruntime package (pip install onnxruntime)") from exc
    if int(crops) < 1:
        raise ValueError(f"crops: expected at least 1 calibration crop, got {crops}")
    checkpoint = Path(checkpoint)
    from ..regressors.models import available_models, model_kind
    from ..regressors.checkpoints import load_checkpoint

    model = load_checkpoint(checkpoint).get("config", {}).get("model")
    if model in available_models() and model_kind(model) != "keypoints":
        raise ValueError(f"checkpoint: {checkpoint} holds a direct {model!r} model; only keypoint models (default, "
                         "keypoints) are quantized")
    # the float ONNX export (what the 8-bit model starts from) records the crops; the expert's crops calibrate
    # its own file
    reg = CheckpointRegressor(checkpoint, engine="onnxruntime", edge_on_expert=None)
    items = [(s, i) for s in map(BopScene, find_scenes(data)) for i in s.image_ids]
    if not items:
        raise ValueError(f"data: {data} holds no images")

    frames = (Frame(scene.rgb(i), scene.image(i).camera, 0.0) for scene, i in items)
    x = record_crops(reg, frames, int(crops), progress)
    if len(x) == 0:
        raise ValueError(f"data: the regressor found no object in any view of {data}: nothing to calibrate on")

    class Crops(CalibrationDataReader):
        def __init__(self) -> None:
            self.rows = iter(x[:, None])

        def get_next(self):
            row = next(self.rows, None)
            return None if row is None else {"x": row}

    out = int8_path(checkpoint) if out is None else Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        src, pre = Path(tmp) / "float.onnx", Path(tmp) / "pre.onnx"
        src.write_bytes(reg.engine.model)
        # symbolic shape inference stops at the traced input checks; ONNX's own shape inference suffices
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        quantize_static(str(pre), str(Path(tmp) / "int8.onnx"), Crops(), quant_format=QuantFormat.QOperator,
                        per_channel=True, reduce_range=True, activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QInt8,
                        calibrate_method=CalibrationMethod.MinMax, op_types_to_quantize=list(QUANTIZED_OPS),
                        nodes_to_exclude=list(FLOAT_NODES))
        import onnx

        model = onnx.load(str(Path(tmp) / "int8.onnx"))
    record = {"checkpoint": checkpoint.name, "checkpoint_sha256": file_sha256(checkpoint),
              "image_size": reg.image_size, "twin_head": reg.engine.has_twin, "data": str(data), "crops": int(len(x))}
    entry = model.metadata_props.add()
    entry.key, entry.value = META_KEY, json.dumps(record)
    atomic_write_bytes(out, model.SerializeToString())  # what onnx.save writes for a model under 2 GB
    return {"path": str(out), **record}
