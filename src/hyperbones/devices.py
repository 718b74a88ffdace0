"""The torch device a command runs on."""

from __future__ import annotations

import torch

from hyperbones.errors import ParameterError


def pick_device(name: str) -> torch.device:
    """``auto``: CUDA when present, else the CPU; a CUDA device asked for without CUDA is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ParameterError(f"device {name!r} asked for, but CUDA is not available")
    return torch.device(name)


def cpu_has_bfloat16() -> bool:
    """Whether oneDNN runs bfloat16 natively on this CPU (AVX512-BF16 or AMX); False if unknown.
    Without such units bfloat16 products are emulated and slower than float32's."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def runs_bfloat16_natively(device: torch.device) -> bool:
    """Whether bfloat16 products run natively on ``device``: CUDA where the GPU supports it, a
    CPU with AVX512-BF16 or AMX (``cpu_has_bfloat16``). Elsewhere they are emulated: on an AMD
    EPYC without them the shipped Conv-MLP took 74-81 ms in bfloat16 against 13 ms in float32
    (docs/experiments/2026-11-30-bfloat16-where-native.md)."""
    if device.type == "cuda":  # not counting emulation (GPUs before Ampere)
        return torch.cuda.is_bf16_supported(including_emulation=False)
    return device.type == "cpu" and cpu_has_bfloat16()
