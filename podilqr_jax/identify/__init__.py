"""Identification: the information state, the least-squares and IV ARMA fits, the exact
linearisation, and the strategies (data-based, exact) the driver calls."""

from .. import _runtime  # noqa: E402,F401  (JAX set up before anything here traces)
