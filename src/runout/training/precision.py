"""Whether bfloat16 pays on this CPU: the check both learned engines' `--bf16` make before
autocasting their networks."""

from __future__ import annotations

import torch


def cpu_has_native_bf16() -> bool:
    """Whether this CPU multiplies bfloat16 natively (AVX512-BF16 or AMX, as oneDNN sees it).
    Elsewhere PyTorch multiplies bfloat16 in a generic kernel, about 14 times slower than
    float32 (AVX2-only AMD EPYC, measured 2026-12-02)."""
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


# What --bf16 says where the CPU lacks native bfloat16 (both engines then train in float32)
NO_NATIVE_BF16 = ("--bf16: this CPU has no native bfloat16 (AVX512-BF16 or AMX), where bfloat16 is about 14 times "
                  "slower than float32; training in float32 instead.")
