"""The allegro_cylinder task definition shared by the MJX environment (envs/allegro.py) and MuJoCo C
(AllegroC here, as envs/mujoco_c.py's make_c gives it): the MJCF, constants, and the task's step in plain MuJoCo C.
No JAX here.
The task itself is described in envs/allegro.py.
"""

from pathlib import Path

import mujoco
import numpy as np

ASSET = Path(__file__).parent / "assets" / "allegro_cylinder.xml"
TIMESTEP = 0.005  # s, physics step (in the MJCF)
SUBSTEPS = 2  # physics steps per 100 Hz control step
ACTION_SCALE = 0.025  # rad of PD-target change per control step at |a| = 1 (2.5 rad/s)
ACTION_COST = 0.01
TARGET_NOISE = 0.005  # rad, start jitter of the PD targets
TAXELS = 18  # tactile elements per finger (paper); the observation is their average
DEFAULT_EPISODE_LENGTH = 200
FINGER_TIPS = ("ff_tip", "th_tip")


def load_mj_model():
    """The MuJoCo C model of the task (the same MJCF MJX steps)."""
    m = mujoco.MjModel.from_xml_path(str(ASSET))
    if abs(m.opt.timestep - TIMESTEP) > 1e-12:
        raise ValueError(f"{ASSET} has timestep {m.opt.timestep}, expected {TIMESTEP}")
    return m


def finger_qpos(m):
    """qpos addresses [nu] of the actuated finger joints (the observation's joint positions), in actuator order."""
    return np.array([m.jnt_qposadr[m.actuator_trnid[i, 0]] for i in range(m.nu)])


def hinge_qpos(m):
    """qpos address of the cylinder's hinge angle."""
    return int(m.jnt_qposadr[m.joint("object_hinge").id])


def tactile_numpy(m, d):
    """MuJoCo C reference of the tactile observation: mj_contactForce normal forces summed per
    fingertip, / TAXELS. (2,)"""
    out = np.zeros(len(FINGER_TIPS))
    tips = [m.geom(name).id for name in FINGER_TIPS]
    f = np.zeros(6)
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, f)
        for k, g in enumerate(tips):
            if g in (d.contact.geom1[i], d.contact.geom2[i]):
                out[k] += f[0]
    return out / TAXELS


def observe_mujoco(m, d):
    """The observation (10,) of a MuJoCo C MjData (after mj_forward or mj_step)."""
    return np.concatenate([d.qpos[finger_qpos(m)], tactile_numpy(m, d)]).astype(np.float32)


def step_mujoco(m, d, action):
    """One control step of the task in MuJoCo C (no MJX, no JAX), in place: the same action
    clipping, PD-target update, substeps and reward as AllegroCylinder.step. Returns (obs, reward)."""
    a = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
    if a.shape != (m.nu,):
        raise ValueError(f"action has shape {a.shape}; allegro_cylinder takes ({m.nu},)")
    lo, hi = m.actuator_ctrlrange.T
    d.ctrl[:] = np.clip(d.ctrl + ACTION_SCALE * a, lo, hi)
    hinge = hinge_qpos(m)
    angle0 = d.qpos[hinge]
    mujoco.mj_step(m, d, nstep=SUBSTEPS)
    reward = (d.qpos[hinge] - angle0) / (TIMESTEP * SUBSTEPS) - ACTION_COST * float(a @ a)
    return observe_mujoco(m, d), float(reward)


def load_tactile_model():
    """The task's model with one MuJoCo contact sensor per fingertip (data "found force", one slot for
    every contact the tip's explicit pairs can make: 2 per capsule pair), so batched MuJoCo C can report
    the tactile observation through sensordata. Sensors do not act on the simulation: the state evolves
    bit for bit as in load_mj_model(). Returns (model, slots per tip)."""
    spec = mujoco.MjSpec.from_file(str(ASSET))
    m = spec.compile()
    slots = []
    for tip in FINGER_TIPS:
        g = m.geom(tip).id
        slots.append(2 * int(np.sum((m.pair_geom1 == g) | (m.pair_geom2 == g))))
        field = mujoco.mjtConDataField
        data = (1 << int(field.mjCONDATA_FOUND)) | (1 << int(field.mjCONDATA_FORCE))  # a bit per field
        spec.add_sensor(name=f"tactile_{tip}", type=mujoco.mjtSensor.mjSENS_CONTACT, objtype=mujoco.mjtObj.mjOBJ_GEOM,
                        objname=tip, intprm=[data, 0, slots[-1]])
    return spec.compile(), slots


def tactile_from_sensordata(sensordata, slots):
    """The tactile observation [..., 2] from load_tactile_model()'s sensordata [..., sum(4 slots)]: each
    slot holds (found, normal force, two tangential forces); the normal forces summed per tip / TAXELS."""
    out, start = [], 0
    for n in slots:
        out.append(sensordata[..., start:start + 4 * n].reshape(*sensordata.shape[:-1], n, 4)[..., 1].sum(-1))
        start += 4 * n
    return np.stack(out, -1) / TAXELS


class AllegroC:
    """envs/allegro.py's allegro_cylinder in MuJoCo C (no termination; the time limit is the caller's)."""

    def __init__(self):
        self.model = load_mj_model()
        self.data = mujoco.MjData(self.model)
        self.dt = TIMESTEP * SUBSTEPS

    @property
    def action_size(self):
        return self.model.nu

    def reset(self, seed):
        rng = np.random.default_rng(seed)
        m, d = self.model, self.data
        mujoco.mj_resetDataKeyframe(m, d, m.key("grasp").id)
        lo, hi = m.actuator_ctrlrange.T
        d.ctrl[:] = np.clip(d.ctrl + TARGET_NOISE * rng.normal(size=m.nu), lo, hi)
        d.qpos[hinge_qpos(m)] = rng.uniform(-np.pi, np.pi)
        mujoco.mj_forward(m, d)
        return observe_mujoco(m, d)

    def observe(self):
        return observe_mujoco(self.model, self.data)

    def step(self, action):
        obs, reward = step_mujoco(self.model, self.data, action)
        return obs, reward, False


def allegro_layout(model):
    """allegro_cylinder's observation layout: the finger joints' positions, then the two tactile means."""
    joints = [model.joint(model.actuator_trnid[i, 0]).name for i in range(model.nu)]
    return [f"{j} position" for j in joints] + ["index tactile (mean taxel force)", "thumb tactile (mean taxel force)"]
