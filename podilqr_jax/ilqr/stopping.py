"""Why a solve stops: every stopping rule of the driver, each returning a :class:`Stop` or None.

The rules in the order the driver meets them in an iteration:

1. identification (``identification_stop``, ``exact_model_stop``): the
   problem ``identify`` reports of its model (``Identified.problem``): too
   many sysid rollouts diverged, the fitted or exact model is not finite, or
   the perturbations moved no observation (``nonfinite``, ``no_response``);
2. backward pass (``backward_stop``): a noiseless backward pass that needs mu
   above ``mu_max`` (``line_search_failed``), or a gradient below ``gtol``
   (``converged``);
3. an accepted step (``accepted_stop``): a relative decrease below ``rtol``
   (``converged``, noiseless only);
4. a rejected noiseless step (``rejected_stop``): a predicted decrease below
   ``rtol`` x cost (``converged``), or mu past ``mu_max`` with every recovery
   spent (``line_search_failed``, with the numbers the line search measured);
5. around the loop: a non-finite first nominal, ``max_iterations``, Ctrl-C,
   a checkpoint of a finished solve (``initial_stop``, ``iterations_stop``,
   ``interrupted``, ``resumed_stop``).
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from .config import SolverConfig, reidentify_scale
from .result import Status


class Stop(NamedTuple):
    """A stopping rule that fired: the status and a message in the numbers that made it fire."""

    status: Status
    message: str


def interrupted(signum: Optional[int]) -> Stop:
    """A stop asked for by Ctrl-C or a scheduler's signal (``interrupts``)."""
    from .interrupts import signal_name

    by = "Ctrl-C" if signum is None else signal_name(signum)
    return Stop(Status.INTERRUPTED, f"{by}; the result is the nominal and gains of the last completed iteration")


def identification_stop(found, n_s: int, sigma: float) -> Optional[Stop]:
    """A data-based identification ``found`` (``identify.Identified``) that
    cannot be used: ``found.n_bad`` of ``n_s`` rollouts diverged leaving fewer
    than the fit needs, a non-finite model, or no response."""
    if found.problem == "diverged":
        n_good = n_s - found.n_bad
        return Stop(
            Status.NONFINITE,
            f"{found.n_bad} of {n_s} sysid rollouts diverged (non-finite states); the {n_good} left are "
            f"too few for the fit ({found.needed} needed): lower sigma, or look at the model's stability",
        )
    if found.problem == "nonfinite":
        return Stop(Status.NONFINITE, "the fitted model is not finite")
    if found.problem == "no_response":
        return Stop(
            Status.NO_RESPONSE,
            f"the sysid perturbations (sigma={sigma:g}) left every observation unchanged, "
            "so the fit sees no dynamics: raise sigma (or use float64, see docs/algorithm.md)",
        )
    return None


def exact_model_stop(found, hint: str, jacobian: str = "exact") -> Optional[Stop]:
    """The model-based linearisation ``found`` (``jacobian``: ``exact`` or
    ``differences``) is not finite (``hint``: what in the model may make the
    exact one so) or moves nothing."""
    what = "exact linearisation" if jacobian == "exact" else "linearisation by central differences"
    if found.problem == "nonfinite":
        return Stop(Status.NONFINITE, f"the {what} is not finite" + (hint if jacobian == "exact" else ""))
    if found.problem == "no_response":
        return Stop(
            Status.NO_RESPONSE,
            f"the {what} has B_t = 0 at every step: the controls move nothing in it, so its gradient is "
            "that of the control cost alone and no reference optimum can be read from it"
            + ("; try jacobian='differences'" if jacobian == "exact" else ""),
        )
    return None


def backward_stop(ok: bool, grad_norm: float, noisy: bool, cfg: SolverConfig) -> Optional[Stop]:
    """After the backward pass: no finite regularisation up to mu_max (noiseless), or a small gradient."""
    if not ok and not noisy:
        return Stop(Status.LINE_SEARCH_FAILED, f"the backward pass needs regularisation above mu_max={cfg.mu_max:g}")
    if ok and grad_norm < cfg.gtol:
        return Stop(Status.CONVERGED, f"gradient norm {grad_norm:.3g} below gtol={cfg.gtol:g}")
    return None


def accepted_stop(decrease: float, new_cost: float, noisy: bool, cfg: SolverConfig) -> Optional[Stop]:
    """After an accepted step: a noiseless relative decrease below rtol."""
    if not noisy and decrease < cfg.rtol * abs(new_cost):
        return Stop(Status.CONVERGED, f"relative cost decrease below rtol={cfg.rtol:g}")
    return None


def small_prediction_stop(predicted: float, cost: float, cfg: SolverConfig) -> Optional[Stop]:
    """After a rejected noiseless step: the model predicts no decrease worth a step."""
    if abs(predicted) < cfg.rtol * abs(cost):
        return Stop(
            Status.CONVERGED,
            f"no step lowers the cost and the predicted decrease {predicted:.3g} is below rtol x cost",
        )
    return None


def line_search_failed(cfg: SolverConfig, streak: int, tried: list[str], ls, steps, cost0: float, reidentify: int):
    """Mu passed mu_max with every recovery spent: why the last (noiseless) line
    search failed, in the numbers it measured; ``steps`` are its candidate step
    sizes, ``tried`` the experiments the recovery switched to."""
    expected = np.asarray(ls.expected)
    costs = np.where(np.isfinite(np.asarray(ls.costs)), np.asarray(ls.costs), np.inf)
    i = int(np.argmin(costs))
    scales = ", ".join(f"x {reidentify_scale(a):g}" for a in range(1, reidentify + 1))
    again = f" and {reidentify} re-identifications (sigma {scales})" if reidentify else ""
    if tried:
        again += ", then the same with " + ", then ".join(tried)
    change = f"changed the cost by {costs[i] - cost0:+.3g}" if np.isfinite(costs[i]) else "diverged"
    return Stop(
        Status.LINE_SEARCH_FAILED,
        f"no step size lowered the cost after {streak} retries with growing regularisation{again}; "
        f"mu passed mu_max={cfg.mu_max:g}. The last model predicted a decrease of {expected[0]:.3g} for the full "
        f"step; the best candidate (alpha = {steps[i]:.3g}, predicted {expected[i]:.3g}) {change}",
    )


def initial_stop(cost: float) -> Optional[Stop]:
    if not np.isfinite(cost):
        return Stop(Status.NONFINITE, "the initial controls give a non-finite rollout")
    return None


def resumed_stop(stopped: Optional[list]) -> Optional[Stop]:
    """A checkpoint of a solve that had stopped: its stop, marked as such."""
    if stopped is None:
        return None
    return Stop(Status(stopped[0]), stopped[1] + " (before the checkpoint)")


def iterations_stop(cfg: SolverConfig, noisy: bool) -> Stop:
    message = f"reached max_iterations={cfg.max_iterations}"
    if noisy:
        message += " (under noise a solve runs to max_iterations; see true_cost_history)"
    return Stop(Status.MAX_ITERATIONS, message)
