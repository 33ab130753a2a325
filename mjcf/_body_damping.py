"""Linear damping in the body frame of a planar body, as a MuJoCo passive force.

MJCF's damping elements (joint and tendon ``damping``, actuator velocity feedback) all have the
form −Jᵀ b J q̇: symmetric, and along fixed joint axes. A vessel's hydrodynamic damping −D ν acts
in the body frame, and the paper's D is not symmetric. A model that needs that declares

    <custom>
      <numeric name="body_damping" data="D11 D12 D13  D21 D22 D23  D31 D32 D33"/>
      <text name="body_damping_joints" data="x y psi"/>
    </custom>

with the joints of a planar body: slides along the world x and y axes and the heading hinge. The
force added to ``qfrc_passive`` in ``mj_passive`` (so at every stage of every ``mj_forward`` and
``mj_step``) is

    qfrc_passive += −[P(ψ) 0; 0 1] D ν,    ν = [P(ψ)ᵀ 0; 0 1] q̇ = [u, v, r],

P(ψ) the planar rotation. MuJoCo offers one hook for it, the process-wide callback
``mjcb_passive``; nothing in MJCF produces D's skew (sway–yaw) part (docs/vessel.md).

``forces(model)`` is what a plant module names as ``PlantInfo.passive_forces``: the force function
of one compiled model, with its layout and D read once. The testbed never leaves it installed:
``cosim.plant.physics`` installs it as ``mjcb_passive`` for the duration of each MuJoCo call on
the plant's model and restores the previous callback afterwards (docs/process-state.md).

``passive(model, data)`` is a stand-alone ``mjcb_passive`` for any model (models without
``body_damping`` are left alone), for simulating the XML by hand, e.g. in MuJoCo's viewer:
``mujoco.set_mjcb_passive(passive)``; whoever installs it owns the process-wide state. It reads
the layout and D at every call, as the testbed did before the callback was scoped to a step, and
gives the same forces bit for bit (tests/test_vessel.py).
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable

import mujoco

NUMERIC = "body_damping"
JOINTS = "body_damping_joints"

#: A passive-force function: adds to ``data.qfrc_passive`` of its model.
Force = Callable[[mujoco.MjModel, mujoco.MjData], None]

#: Per model: (numeric address, dof addresses of x, y, psi, qpos address of psi), or None.
_layout: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def layout(model: mujoco.MjModel) -> tuple[int, int, int, int, int] | None:
    """Where the callback reads D and the planar coordinates; None for a model without ``body_damping``.

    Raises ValueError naming what is wrong if the declaration is incomplete.
    """
    nid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, NUMERIC)
    if nid < 0:
        return None
    if model.numeric_size[nid] != 9:
        raise ValueError(
            f"custom numeric {NUMERIC!r} has {model.numeric_size[nid]} values; give the 3x3 matrix D row by row (9)"
        )
    tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, JOINTS)
    if tid < 0:
        raise ValueError(
            f"custom numeric {NUMERIC!r} needs a custom text {JOINTS!r} naming the x, y and heading joints"
        )
    start = model.text_adr[tid]
    names = model.text_data[start : start + model.text_size[tid]].split(b"\0")[0].decode().split()
    kinds = (mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE)
    if len(names) != 3:
        raise ValueError(
            f"custom text {JOINTS!r} names {len(names)} joints; name three: x slide, y slide, heading hinge"
        )
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name) for name in names]
    for name, jid, kind in zip(names, ids, kinds):
        if jid < 0 or model.jnt_type[jid] != kind:
            raise ValueError(f"custom text {JOINTS!r}: {name!r} is not a {kind.name[6:].lower()} joint of the model")
    ix, iy, ir = (int(model.jnt_dofadr[j]) for j in ids)
    return int(model.numeric_adr[nid]), ix, iy, ir, int(model.jnt_qposadr[ids[2]])


def passive(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """mjcb_passive for any model: add −[P(ψ) 0; 0 1] D ν to ``data.qfrc_passive`` of a model with
    ``body_damping``, leave other models alone. Not used by the testbed (see ``forces``)."""
    try:
        where = _layout[model]
    except KeyError:
        where = _layout[model] = layout(model)
    if where is None:
        return
    adr, ix, iy, ir, ipsi = where
    D = model.numeric_data[adr : adr + 9].tolist()
    qvel = data.qvel
    psi = float(data.qpos[ipsi])
    c, s = math.cos(psi), math.sin(psi)
    xd, yd, r = float(qvel[ix]), float(qvel[iy]), float(qvel[ir])
    u, v = c * xd + s * yd, -s * xd + c * yd
    fu = -(D[0] * u + D[1] * v + D[2] * r)
    fv = -(D[3] * u + D[4] * v + D[5] * r)
    fr = -(D[6] * u + D[7] * v + D[8] * r)
    qfrc = data.qfrc_passive
    qfrc[ix] += c * fu - s * fv
    qfrc[iy] += s * fu + c * fv
    qfrc[ir] += fr


def forces(model: mujoco.MjModel) -> Force | None:
    """The body-frame damping of ``model`` as a force function f(model, data), or None for a model
    without ``body_damping`` (ValueError naming what is wrong for an incomplete declaration).

    Layout and D are read now: f is for this model only, and leaves any other model alone
    (changing ``model.numeric_data`` later changes nothing; build another). f reads ψ and q̇ from
    ``data`` and adds the force to ``data.qfrc_passive`` with the same operations, in the same
    order, as ``passive``: the same bits. It keeps views of the arrays of the last MjData it saw (a
    plant steps one MjData). MuJoCo calls it in every ``mj_passive``, 41 times per tick of the
    vessel (RK4, 10 steps, and the forward pass), which makes its Python the larger part of the
    vessel's physics.
    """
    where = layout(model)
    if where is None:
        return None
    own = model
    adr, ix, iy, ir, ipsi = where
    D11, D12, D13, D21, D22, D23, D31, D32, D33 = model.numeric_data[adr : adr + 9].tolist()
    last: list = [None, None, None, None]  # data, its qvel, qpos, qfrc_passive

    def damping(model: mujoco.MjModel, data: mujoco.MjData) -> None:
        if model is not own:
            return
        if data is last[0]:
            _, qvel, qpos, qfrc = last
        else:  # memoryviews of MjData's arrays: indexing one costs a third of an array's item() or +=
            qvel, qpos, qfrc = memoryview(data.qvel), memoryview(data.qpos), memoryview(data.qfrc_passive)
            last[:] = data, qvel, qpos, qfrc
        psi = qpos[ipsi]
        c, s = math.cos(psi), math.sin(psi)
        xd, yd, r = qvel[ix], qvel[iy], qvel[ir]
        u, v = c * xd + s * yd, -s * xd + c * yd
        fu = -(D11 * u + D12 * v + D13 * r)
        fv = -(D21 * u + D22 * v + D23 * r)
        fr = -(D31 * u + D32 * v + D33 * r)
        qfrc[ix] += c * fu - s * fv
        qfrc[iy] += s * fu + c * fv
        qfrc[ir] += fr

    return damping
