"""Linear damping in the body frame of a planar body, as MuJoCo passive force.

MJCF's damping elements (joint and tendon ``damping``, actuator velocity feedback) all have the
form −Jᵀ b J q̇: symmetric, and along fixed joint axes. A vessel's hydrodynamic damping −D ν acts
in the body frame, and the paper's D is not symmetric. A model that needs that declares

    <custom>
      <numeric name="body_damping" data="D11 D12 D13  D21 D22 D23  D31 D32 D33"/>
      <text name="body_damping_joints" data="x y psi"/>
    </custom>

with the joints of a planar body: slides along the world x and y axes and the heading hinge. This
callback then adds, in ``mj_passive`` (so in every ``mj_forward`` and ``mj_step``),

    qfrc_passive += −[P(ψ) 0; 0 1] D ν,    ν = [P(ψ)ᵀ 0; 0 1] q̇ = [u, v, r],

P(ψ) the planar rotation. Models without ``body_damping`` are left alone. A plant module names
``passive`` as its ``PlantInfo.passive``; ``cosim.plant.physics.load_model`` installs it (MuJoCo's callbacks
are global: a Python one cannot run while a model compiles, so load_model compiles without it).
"""

from __future__ import annotations

import math
import weakref

import mujoco

NUMERIC = "body_damping"
JOINTS = "body_damping_joints"

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
    return (int(model.numeric_adr[nid]), *(int(model.jnt_dofadr[j]) for j in ids), int(model.jnt_qposadr[ids[2]]))


def passive(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """mjcb_passive: add −[P(ψ) 0; 0 1] D ν to ``data.qfrc_passive`` for a model with ``body_damping``."""
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
