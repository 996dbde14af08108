"""How loud the backends are in a terminal: XLA's C++ log lines and JAX's
logger warnings, hidden unless ``--verbose`` or ``PODILQR_VERBOSE=1`` asks for
them. Imports neither JAX nor MuJoCo (it must run before they load), so every
command line of the package (``podilqr`` and ``podilqr bench``) can call it first.
"""

from __future__ import annotations

import os

from . import environment

VERBOSE_HELP = "show XLA's and JAX's own log lines and alarms (also PODILQR_VERBOSE=1)"


def quiet_backends(verbose: bool) -> None:
    """Keep XLA's and JAX's own alarms out of the terminal: XLA's C++ log lines
    (such as "Constant folding an instruction is taking > 1s", an ERROR-level
    line about compile time, not about the result) and the warnings of JAX's
    logger. ``--verbose`` or ``PODILQR_VERBOSE=1`` keeps them, and so does a
    ``TF_CPP_MIN_LOG_LEVEL`` the user set. Called before JAX is imported."""
    if verbose or environment.switch(environment.VERBOSE, False):
        return
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    import logging

    logging.getLogger("jax").setLevel(logging.ERROR)
