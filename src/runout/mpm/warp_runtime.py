"""Warp's runtime started quietly: `start_warp()` instead of `wp.init()`.

Warp's native library looks for the NVIDIA CUDA driver when it starts, and on a machine without
one its C code writes "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver" to the
process's stderr (file descriptor 2, not Python's sys.stderr), whatever device was asked for;
Warp 1.19 has no setting that skips the probe. runout decides the device itself (--device is
checked against torch before any run: `--device cuda` without a GPU stops with one sentence),
so that line says nothing a user can act on. start_warp() catches what the native start writes
to descriptor 2 and passes on every line but that one. Its device banner goes to stdout only
above log level WARNING, which runout keeps it at.
"""

from __future__ import annotations

import os
import sys
import tempfile

import warp as wp

NO_DRIVER = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"

wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)  # no device banner or per-module load lines on stdout


_started = False  # whether start_warp has run in this process (wp.init starts once)


def start_warp() -> None:
    """wp.init(), with the missing-CUDA-driver warning left out of stderr; other lines pass."""
    global _started
    if _started:
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            wp.init()
            _started = True
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        caught.seek(0)
        text = caught.read().decode(errors="replace")
    kept = [line for line in text.splitlines(keepends=True) if not line.startswith(NO_DRIVER)]
    if kept:
        sys.stderr.write("".join(kept))
        sys.stderr.flush()
