"""How heavy a model's MJX step is: its constraint rows, and what that decides.

MJX sizes its constraint solver for every contact, limit, friction loss and
equality row the model could ever have, so the row count is fixed per model
and readable from the shapes of its data before anything compiles
(:func:`constraint_rows`). The models the project has measured fall on two
sides of a wide gap: at most 3 rows (no contacts: the bundled tasks and the
dm_control and Gymnasium models without a floor) or at least 38 (the
Gymnasium hopper 38, dm_control's finger 93; from dm_control's suite also
walker 62, ball-in-cup 65, hopper 88, cheetah 146, humanoid 303).

On a model with contacts (:func:`contact_rich`, ``MANY_ROWS`` rows or
more) the model-based reference on MJX linearises by central differences of
the step (:func:`jacobian`, unless the solve's ``jacobian`` setting says
otherwise): MJX's forward-mode derivative at an active contact is NaN under
the elliptic friction cone (dm_control's finger), and its program, the step
with its tangent, took 1.9-2.1x as long in XLA's compiler as the
differences' one copy of the step, whose trace the line search's program
shares (benchmarks/journal.md). Under ``engine = "auto"`` such a model runs
on the native engine on a CPU (``sim.engines``); this applies where MJX
runs it (a GPU, or ``engine = "mjx"``).
"""

from __future__ import annotations

import jax

from .rollout import make_data

MANY_ROWS = 32  # constraint rows from which a model counts as contact-rich


def constraint_rows(model) -> int:
    """The constraint rows MJX's step carries for ``model`` (a fixed count in
    MJX: every possible contact, limit, friction loss and equality row), read
    from the shapes of its data without touching a device; 0 where this MJX
    or implementation does not say."""
    d = jax.eval_shape(make_data, model)
    efc_J = getattr(getattr(d, "_impl", d), "efc_J", None)
    return 0 if efc_J is None else int(efc_J.shape[0])


def many_rows(rows: int) -> bool:
    """Whether ``rows`` constraint rows make a model contact-rich (at least ``MANY_ROWS``)."""
    return rows >= MANY_ROWS


def contact_rich(model) -> bool:
    """Whether ``model``'s MJX step carries at least ``MANY_ROWS`` constraint rows."""
    return many_rows(constraint_rows(model))


def jacobian(setting: str, model, floating: bool = False) -> str:
    """The model-based reference's linearisation (``model_based.JACOBIANS``)
    for the solve's ``jacobian`` setting: ``auto`` is ``differences`` on a
    contact-rich model (module docstring) and on a ``floating`` one (a free
    or ball joint), ``exact`` otherwise.

    On a floating model MJX's forward-mode derivative of the quaternion's
    integration is zero at zero angular rate, so at rest the linearisation
    says a torque does not turn the body: a floating box asked to turn by 90
    degrees (tests/test_tangent.py) stops at a nominal that never turns,
    where central differences turn it."""
    if setting != "auto":
        return setting
    return "differences" if floating or contact_rich(model) else "exact"
