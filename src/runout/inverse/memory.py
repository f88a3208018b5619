"""Peak memory of one forward + backward pass.

On CUDA: torch.cuda.max_memory_allocated over the pass (every tensor, model included).
On CPU there is no allocator statistic and the process RSS hides freed-but-cached memory,
so we count what grows with rollout length: the bytes of tensors autograd holds for the
backward pass, through saved-tensor hooks (each storage counted once while it is held).
Tensors saved inside a checkpointed step's recomputation are not seen; they live for one
step only.
"""

from __future__ import annotations

import torch

MEASURES = {"cuda": "torch.cuda.max_memory_allocated", "cpu": "bytes held by autograd saved-tensor hooks"}


class PeakMemory:
    """Context manager; after it, `.peak_bytes` is the peak over the block."""

    def __init__(self, device: torch.device | str):
        self.device = torch.device(device)
        self.peak_bytes = 0
        self._held: dict[int, list[int]] = {}  # storage address -> [bytes, holders]
        self._live = 0
        self._hooks = None

    @property
    def measure(self) -> str:
        return MEASURES["cuda" if self.device.type == "cuda" else "cpu"]

    def __enter__(self) -> "PeakMemory":
        if self.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(self.device)
        else:
            self._hooks = torch.autograd.graph.saved_tensors_hooks(self._pack, _unpack)
            self._hooks.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self.device.type == "cuda":
            self.peak_bytes = int(torch.cuda.max_memory_allocated(self.device))
        else:
            self._hooks.__exit__(*exc)

    def _pack(self, tensor: torch.Tensor) -> "_Held":
        storage = tensor.untyped_storage()
        key = storage.data_ptr()
        entry = self._held.setdefault(key, [storage.nbytes(), 0])
        if entry[1] == 0:
            self._live += entry[0]
            self.peak_bytes = max(self.peak_bytes, self._live)
        entry[1] += 1
        return _Held(tensor, key, self)

    def _release(self, key: int) -> None:
        entry = self._held[key]
        entry[1] -= 1
        if entry[1] == 0:
            self._live -= entry[0]
            del self._held[key]


class _Held:
    """A saved tensor; when autograd drops it, its bytes stop counting."""

    def __init__(self, tensor: torch.Tensor, key: int, meter: PeakMemory):
        self.tensor = tensor
        self.key = key
        self.meter = meter

    def __del__(self) -> None:
        self.meter._release(self.key)


def _unpack(held: _Held) -> torch.Tensor:
    return held.tensor
