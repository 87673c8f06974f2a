"""Where a keypoint network runs at inference: ONNX Runtime on the CPU (the default, ``"auto"``: the
checkpoint's 8-bit model where it has one, else float32) or torch.

ONNX Runtime's CPU kernels run the shipped 128-px keypoint network ≈ 1.6× as fast as torch's at
batch 1 on one thread (4.4 vs 7.0 ms a call on an AVX2 EPYC; `benchmarks/inference_engines.py`) with the same outputs to float rounding, and that call is a third to a half of
``predict``'s time. Float rounding sends ≈ 1 % of views down another branch of the path (a keypoint
just inside or outside a PnP threshold); a test on 16 000 fresh views, written before they were
rendered, found the two engines equivalent within ±0.25° mean rotation, so ``engine="auto"`` (the
regressors' default) runs keypoint networks on ONNX Runtime on the CPU, and on torch where ONNX Runtime
is missing, the export fails (the reason logged) or on a GPU. ``engine="onnxruntime"`` asks for it (an
error where it cannot run); ``engine="torch"`` for torch.
``"onnxruntime-int8"`` runs the 8-bit model ``hybridpose quantize`` made
(:mod:`hybridpose.training.quantize`).

``"auto"`` runs that 8-bit model where one made from this very checkpoint
lies beside it (the shipped ``default`` and its edge-on expert; a stale one is skipped with a warning):
as accurate as float32 within the margins a test set before the views were rendered, and faster on the
whole path (the figures: ``docs/decisions.md``).

The network is exported at load (torch's TorchScript-based ONNX exporter: ≈ 0.3 s for the shipped
one; the newer torch.export-based one takes ≈ 6 s) and kept in memory: a checkpoint stays the one
file a user trains, ships and hashes. ONNX Runtime sessions follow torch's thread count
(``torch.set_num_threads``, the regressors' ``threads=``) at each call, so one knob sets both.
"""
from __future__ import annotations

import io
import logging
import time
import warnings

import torch
from torch import nn

log = logging.getLogger(__name__)

ENGINES = ("auto", "torch", "onnxruntime", "onnxruntime-int8")


class _TwinOutputs(nn.Module):
    """``net(x, with_twin=True)`` as a module of one tensor argument (what the exporter traces)."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor):
        return self.net(x, with_twin=True)


class TorchEngine:
    """A keypoint network on torch: ``engine(x)`` → (uv (B, N, 2) crop pixels, spread (B, N) pixels, twin
    logits (B, T) or None), float tensors on the CPU, from ``x`` (B, 3, S, S) float32 in [0, 1] on the CPU."""

    name = "torch"

    def __init__(self, net: nn.Module, device: torch.device, memory_format=torch.contiguous_format) -> None:
        self.net, self.device, self.memory_format = net, device, memory_format

    def __call__(self, x: torch.Tensor):
        with torch.inference_mode():
            uv, spread, twin = self.net(x.to(self.device).contiguous(memory_format=self.memory_format), with_twin=True)
        return uv.float().cpu(), spread.float().cpu(), None if twin is None else twin.float().cpu()


class OnnxModule:
    """A torch module of one tensor argument exported to ONNX (batch dimension dynamic) and run by ONNX
    Runtime's CPU provider, one session per thread count (torch's at each call). ``model``: an ONNX model
    of it to run instead (bytes). Raises RuntimeError (naming ``name`` and the cause) when onnxruntime
    or onnx is missing, the export fails or ONNX Runtime cannot load the model (checked at
    construction, on torch's current thread count)."""

    def __init__(self, module: nn.Module, example: torch.Tensor, output_names: list[str], model: bytes | None = None,
                 name: str = "onnxruntime") -> None:
        try:
            import onnxruntime
        except ImportError as exc:
            raise RuntimeError(f"engine={name!r} needs the onnxruntime package (pip install onnxruntime onnx)") from exc
        self._ort, self.name = onnxruntime, name
        self._sessions: dict[int, object] = {}
        self.model = model if model is not None else self._export(module, example, output_names, name)
        try:  # a model ONNX Runtime cannot load fails here, with its reason, not at the first call
            self.session(torch.get_num_threads())
        except Exception as exc:  # noqa: BLE001 — onnxruntime raises its own exception types
            raise RuntimeError(f"engine={name!r}: ONNX Runtime cannot run the network ({exc})") from exc

    @staticmethod
    def _export(module: nn.Module, example: torch.Tensor, output_names: list[str], name: str) -> bytes:
        buffer = io.BytesIO()
        try:
            with warnings.catch_warnings():
                # the TorchScript exporter is deprecated in favour of torch.export's, 20× slower here; its
                # tracer warns about the nets' input checks, which their callers have made before any call
                warnings.simplefilter("ignore")
                torch.onnx.export(module.cpu().eval(), (example,), buffer, input_names=["x"], output_names=output_names,
                                  dynamic_axes={"x": {0: "batch"}}, opset_version=17, dynamo=False)
        except Exception as exc:  # noqa: BLE001 — any exporter failure means: this net cannot run here
            raise RuntimeError(f"engine={name!r}: exporting the network to ONNX failed ({exc})") from exc
        return buffer.getvalue()

    @property
    def sessions(self) -> dict:
        """The sessions made so far, by intra-op thread count (a copy)."""
        return dict(self._sessions)

    def session(self, threads: int):
        """The ONNX Runtime session running on ``threads`` intra-op threads (made on first use)."""
        if threads not in self._sessions:
            options = self._ort.SessionOptions()
            options.intra_op_num_threads = int(threads)
            options.inter_op_num_threads = 1
            options.graph_optimization_level = self._ort.GraphOptimizationLevel.ORT_ENABLE_ALL
            # every session has its own intra-op pool, and a pool's threads spin after a run by default: a
            # regressor's three networks (keypoints, edge-on expert, twin verifier) on 2 threads then fought
            # each other's spinning threads for the cores, and its whole path took 2× as long as on 1 thread
            # (40–46 vs 20–23 ms/view; 19–22 without spinning, 100 seed-100 views, 2 cores)
            options.add_session_config_entry("session.intra_op.allow_spinning", "0")
            self._sessions[threads] = self._ort.InferenceSession(self.model, options,
                                                                 providers=["CPUExecutionProvider"])
        return self._sessions[threads]

    def __call__(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The module's outputs (float tensors on the CPU) for ``x`` (on the CPU)."""
        outs = self.session(torch.get_num_threads()).run(None, {"x": x.detach().cpu().contiguous().numpy()})
        return [torch.from_numpy(o) for o in outs]


class OnnxRuntimeEngine:
    """The same network exported to ONNX and run by ONNX Runtime's CPU provider (:class:`OnnxModule`);
    same call as :class:`TorchEngine`. ``model``: an ONNX model of it to run instead (bytes; the 8-bit one
    of :mod:`hybridpose.training.quantize`, whose ``name`` is then given). Raises RuntimeError as
    :class:`OnnxModule` does."""

    def __init__(self, net: nn.Module, image_size: int, model: bytes | None = None, name: str = "onnxruntime") -> None:
        self.name = name
        self.has_twin = getattr(net, "twin_head", None) is not None
        example = torch.zeros(1, 3, int(image_size), int(image_size))
        self.onnx = OnnxModule(_TwinOutputs(net.cpu()), example, ["uv", "spread"] + (["twin"] if self.has_twin else []),
                               model=model, name=name)
        self.model = self.onnx.model

    def __call__(self, x: torch.Tensor):
        outs = self.onnx(x)
        return outs[0], outs[1], outs[2] if self.has_twin else None


def keypoint_engine(engine: str, net: nn.Module, device: torch.device, image_size: int,
                    memory_format=torch.contiguous_format, checkpoint=None):
    """The engine named ``engine`` (one of :data:`ENGINES`) for a keypoint ``net`` (eval mode, batch
    norm folded) on ``device``. ``"auto"`` on the CPU: the 8-bit model of ``checkpoint`` where one made
    from this very file lies beside it, else ONNX Runtime in float32 (a stale or unreadable
    8-bit file is skipped with a warning), else torch where ONNX Runtime is missing or the export fails
    (the reason logged); on a GPU torch. ``"onnxruntime-int8"``: the 8-bit model made from ``checkpoint``
    by ``hybridpose quantize`` (beside it, :func:`~hybridpose.regressors.int8_file.int8_path`)."""
    if engine not in ENGINES:
        raise ValueError(f"engine: expected one of {', '.join(ENGINES)}, got {engine!r}")
    if engine.startswith("onnxruntime") and device.type != "cpu":
        raise ValueError(f"engine={engine!r} runs on the CPU; the network is on {device} (use engine='torch')")
    if engine == "onnxruntime-int8":
        from .int8_file import load_int8

        if checkpoint is None:
            raise ValueError("engine='onnxruntime-int8': needs the checkpoint the 8-bit model was made from")
        model, record = load_int8(checkpoint)
        if int(record.get("image_size", -1)) != int(image_size):
            raise ValueError(f"engine='onnxruntime-int8': the 8-bit model of {checkpoint} takes "
                             f"{record.get('image_size')} px crops, the network {image_size}")
        return OnnxRuntimeEngine(net, image_size, model=model, name=engine)
    if engine == "auto" and device.type == "cpu" and checkpoint is not None:
        from .int8_file import int8_path

        if int8_path(checkpoint).is_file():
            try:
                return keypoint_engine("onnxruntime-int8", net, device, image_size, memory_format, checkpoint)
            except (ValueError, RuntimeError) as exc:  # stale (retrained since), corrupt, or no onnxruntime
                log.warning("%s: its 8-bit model is not used (%s); the network runs in float32", checkpoint, exc)
    torch_engine = TorchEngine(net, device, memory_format)
    if engine == "onnxruntime" or (engine == "auto" and device.type == "cpu"):
        try:
            ort_engine = OnnxRuntimeEngine(net, image_size)
        except RuntimeError as exc:
            if engine == "onnxruntime":
                raise
            log.info("keypoint network on torch: %s", exc)
            return torch_engine
        return ort_engine
    return torch_engine


def call_ms(engine, x: torch.Tensor, calls: int = 10, repeats: int = 3, sync=None) -> float:
    """ms of one ``engine(x)`` call at the current thread count: the lowest of ``repeats`` means over
    ``calls`` (after one warm-up call). ``sync``: called after each run of ``calls`` before the clock is
    read (``torch.cuda.synchronize`` for a network on a GPU)."""
    calls, repeats = max(1, int(calls)), max(1, int(repeats))
    engine(x)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            engine(x)
        if sync is not None:
            sync()
        best = min(best, 1000 * (time.perf_counter() - t0) / calls)
    return best
