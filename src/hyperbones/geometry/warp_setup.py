"""Warp (NVIDIA's kernel library, used by Anny and the body proximity) initialised quietly."""

from __future__ import annotations

import os
import sys
import tempfile

# Printed by Warp's native library on every machine without a GPU: expected, not news.
_EXPECTED_WARP_NOISE = ("Could not find or load the NVIDIA CUDA driver",)


def init_warp_quietly() -> None:
    """Initialise Warp (Anny's kernels use it) without its banner or the no-GPU notice.

    The notice comes from native code, so the process's stderr is captured at the file
    descriptor level during ``wp.init()``; any other message is passed on.
    """
    import warp

    warp.config.log_level = warp.LOG_ERROR
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 2)
        try:
            warp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        for line in captured.read().decode(errors="replace").splitlines():
            if line.strip() and not any(noise in line for noise in _EXPECTED_WARP_NOISE):
                print(line, file=sys.stderr)
