"""What a study's numbers were measured on: one description for every report.

``podilqr bench``, ``podilqr reproduce`` and ``podilqr evaluate`` write it into
their JSON under ``"machine"``, so figures from different runs can be told apart
by the CPU, the device, the library versions and the float width.
"""

from __future__ import annotations

import os
import platform
from typing import Any


def describe() -> dict[str, Any]:
    """The CPU (its model name where /proc/cpuinfo has it), the core count, the
    platform, Python, JAX, jaxlib, MuJoCo and NumPy versions, the backend and
    its devices, and whether JAX runs in float64."""
    import jax
    import mujoco
    import numpy as np

    devices = jax.devices()
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            names = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": getattr(jax.lib, "__version__", None) or jax.__version__,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in devices],
        "device_kind": devices[0].device_kind,
        "x64": bool(jax.config.jax_enable_x64),
    }
