"""The robot as a MuJoCo model: a second engine for the recorder of ``sim/truth``.

The model is built at run time from the parameter table (:mod:`host_tools.params`, i.e.
``params/params.json``); no number of the table is written here. What it is:

* **chassis**: a free body whose frame is the axle centre o at wheel-centre height; its mass
  ``m_r`` (plus a ``payload``) sits at the centre of mass c, ``d`` ahead of o at height ``h``
  above the ground; yaw inertia ``I_rz`` about c. Roll and pitch inertias are not in the table:
  0.55 ``I_rz`` each (a flat plate has half of ``I_rz``; they only shape the small pitch and roll
  motions on the soft contacts).
* **wheels**: two hinged bodies at ``+-b`` on the axle (left at +y), mass ``m_w``, inertia
  ``I_wz`` about the vertical and the longitudinal axes and ``I_wz`` about the axle, plus the
  rest of ``I_wy`` (rotor and gearbox reflected through the gear) as the hinge's armature, so
  that the spin inertia is ``I_wy``. The rolling surface is a sphere of radius ``r`` (one
  contact point under the axle, no torsional friction: condim 3).
* **ball caster**: a frictionless sphere fixed to the chassis ``e`` ahead of c (condim 1), or
  with Coulomb friction ``mu`` for ``caster_drag`` (condim 3).
* **contacts**: MuJoCo's soft contacts (elliptic friction cones, :data:`CONTACT`).
* **friction with mu_s and mu_k**: MuJoCo's contact has one friction coefficient. Each step the
  engine sets each wheel's coefficient from its slip state after the previous step: ``mu_s``
  while the contact point's slip speed is below :data:`SLIP_ON_M_S` (stick), ``mu_k`` (or the
  Stribeck law) once it is above, back to ``mu_s`` below :data:`SLIP_OFF_M_S`. What that does
  to the stick/slip transition: breakaway happens when the traction reaches ``mu_s N`` (the
  cone in force during the step); the drop to ``mu_k`` comes once the slip speed passes
  :data:`SLIP_ON_M_S` — a few steps where the demand rises well past the cone, but a contact
  held just above it creeps at ``mu_s`` under the threshold for tens of ms or for good, a
  pre-sliding creep the nominal model does not carry (docs/suite.md; the analyzer's friction
  single fits it as a creep speed) —, and the
  return to ``mu_s`` needs the slip speed to fall under the lower threshold, so a wheel at the
  limit does not chatter between the two coefficients. The soft cone lets a sticking contact
  creep at well under :data:`SLIP_ON_M_S` (measured: docs/suite.md).
* **motors**: the datasheet DC motor per wheel (``supply_v``, ``no_load_rad_s``, ``stall_nm``,
  ``stall_a``), driven by the applied duty: armature current
  ``I = stall_a (V - k_e' w) / supply_v`` limited to ``+-stall_a``, torque
  ``stall_nm / stall_a`` per ampere, applied as a joint torque on the wheel's hinge. Optional
  electrical inductance (``inductance_h``): the current follows with the time constant
  ``L / R``, ``R = supply_v / stall_a``.

Effects (run-format.md's names), each applied where it is physical in this model:
``friction_coefficient`` (the two coefficients), ``wheel_radius`` (sphere radius and axle
height), ``track_width`` (wheel positions), ``motor_back_emf`` (``k_e'``), ``driver_voltage_drop``
and ``deadband`` (volts), ``actuation_delay`` (the duty is applied ``delay_s`` late),
``motor_lag`` (first-order lag of the current), ``motor_gain_asymmetry`` (torque per ampere
times sqrt(ratio) right, divided by it left), ``axle_viscous`` (hinge damping),
``axle_coulomb`` (hinge dry friction), ``caster_drag`` (the caster's contact friction),
``load_transfer`` (the centre of mass at height ``h``: the 3-D body transfers load by itself,
so the null already has the transfer of the table's ``h``), ``stribeck`` (the sliding
coefficient), ``floor_slope`` (gravity tilted along +x), ``payload`` (``mass_kg`` added at c,
``I_rz`` unchanged). Outside the vocabulary: ``eccentric_wheel`` (the sphere off the axle by
``eps r``), ``battery_sag`` (supply falling with current and charge), ``friction_patch``.

:class:`MujocoRobot` is stepped by the recorder through :meth:`MujocoRobot.step`, the function
``sim/truth``'s ``tr_set_plant`` calls once per step (``host_tools.truth.simulate_run`` with
``engine="mujoco"``). ``mujoco`` is imported when a model is built, not on import.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Mapping

import numpy as np

from host_tools import params as _params

#: MuJoCo's contact settings: soft normal contact (time constant, damping ratio), its
#: impedance, elliptic cones with a high ratio of frictional to normal impedance (little creep)
CONTACT = {"solref": (0.004, 1.0), "solimp": (0.95, 0.99, 0.001), "impratio": 10.0}
#: the engine's step (s); the recorder's step is the same, so every period must be a multiple
DT_S = 2e-4
#: slip speed of a wheel's contact point above which it is sliding (mu_k), m/s
SLIP_ON_M_S = 5e-3
#: slip speed below which a sliding contact sticks again (mu_s), m/s
SLIP_OFF_M_S = 2e-3
#: steps between two evaluations of the normal contact forces (hidden columns only)
FORCES_EVERY = 8
#: settling time before t = 0 (the soft contacts take their load at rest), s
SETTLE_S = 0.3

#: the effects this engine applies and their parameters (defaults: neutral)
EFFECTS = {
    "friction_coefficient": ("mu_s", "mu_k"), "wheel_radius": ("r_eff",),
    "track_width": ("b_eff",), "motor_back_emf": ("ke_ratio",),
    "driver_voltage_drop": ("volts",), "actuation_delay": ("delay_s",), "motor_lag": ("tau_s",),
    "axle_viscous": ("c",), "axle_coulomb": ("torque",), "caster_drag": ("mu",),
    "load_transfer": ("h",), "stribeck": ("mu_k0", "v_s"), "deadband": ("volts",),
    "motor_gain_asymmetry": ("ratio",), "floor_slope": ("rad",), "payload": ("mass_kg",),
    "eccentric_wheel": ("eps", "phase_r", "phase_l"), "battery_sag": ("r_int", "v_per_as"),
    "friction_patch": ("x0", "x1", "factor"),
}

#: the caster ball's radius (not in the table; it only sets where the caster's contact is)
CASTER_RADIUS_FRACTION = 0.4  # of the wheel radius


def _table() -> tuple[dict, dict]:
    t = _params.TABLE
    return t.defaults("robot", run_format_only=False), t.defaults("motor", run_format_only=False)


def check_effects(effects: Mapping | None) -> dict[str, dict[str, float]]:
    """The effects as ``{name: {param: float}}``, or ``ValueError`` naming what is wrong."""
    out: dict[str, dict[str, float]] = {}
    for name, ps in (effects or {}).items():
        if name not in EFFECTS:
            raise ValueError(f"mujoco engine: unknown effect '{name}'; known: {sorted(EFFECTS)}")
        bad = set(ps) - set(EFFECTS[name])
        if bad:
            raise ValueError(f"effect '{name}' has no parameter(s) {sorted(bad)}; it has "
                             f"{list(EFFECTS[name])}")
        try:
            out[name] = {k: float(v) for k, v in ps.items()}
        except (TypeError, ValueError):
            raise ValueError(f"effect '{name}': parameters must be numbers") from None
    return out


class MujocoRobot:
    """The robot in MuJoCo with the given effects (``{name: {param: value}}``), stepped by the
    recorder. ``inductance_h``: the motors' armature inductance (0: the current follows the
    voltage at once). ``dt_s``: the engine's step. ``lumped``: the thesis's mass distribution
    instead of the physical one (both wheels' mass at c and ``2 m_w b^2`` added to the chassis's
    yaw inertia, as lib/slipmodel and the truth simulator have it), for the validation."""

    def __init__(self, effects: Mapping | None = None, inductance_h: float = 0.0,
                 dt_s: float = DT_S, lumped: bool = False):
        import mujoco  # lazy: only this engine needs it
        self._mj = mujoco
        self.effects = check_effects(effects)
        if not 0.0 <= inductance_h <= 1.0:
            raise ValueError(f"inductance_h = {inductance_h:g} H is outside [0, 1]")
        if not 1e-5 <= dt_s <= 2e-3:
            raise ValueError(f"dt_s = {dt_s:g} s is outside [1e-5, 2e-3]")
        self.dt = float(dt_s)
        self.lumped = bool(lumped)
        robot, motor = _table()
        eff = self.effects

        def p(name, param, default):
            return eff.get(name, {}).get(param, default)

        self.mu_s = p("friction_coefficient", "mu_s", robot["mu_s"])
        self.mu_k = min(p("friction_coefficient", "mu_k", robot["mu_k"]), self.mu_s)
        self.r = p("wheel_radius", "r_eff", robot["r"])
        self.b = p("track_width", "b_eff", robot["b"])
        self.ke_ratio = p("motor_back_emf", "ke_ratio", 1.0)
        self.v_drop = p("driver_voltage_drop", "volts", 0.0)
        self.delay = p("actuation_delay", "delay_s", 0.0)
        self.lag = p("motor_lag", "tau_s", 0.0)
        self.c_visc = p("axle_viscous", "c", 0.0)
        self.t_coul = p("axle_coulomb", "torque", 0.0)
        self.mu_caster = p("caster_drag", "mu", 0.0)
        self.h = p("load_transfer", "h", robot["h"])
        self.stribeck = "stribeck" in eff
        self.mu_k0 = p("stribeck", "mu_k0", self.mu_k)
        self.v_s = p("stribeck", "v_s", 0.01)
        self.v_dead = p("deadband", "volts", 0.0)
        self.asym = p("motor_gain_asymmetry", "ratio", 1.0)
        self.slope = p("floor_slope", "rad", 0.0)
        self.payload = p("payload", "mass_kg", 0.0)
        self.ecc = p("eccentric_wheel", "eps", 0.0)
        self.ecc_phase = (p("eccentric_wheel", "phase_r", 0.0), p("eccentric_wheel", "phase_l", 1.3))
        self.r_int = p("battery_sag", "r_int", 0.0)
        self.v_per_as = p("battery_sag", "v_per_as", 0.0)
        self.patch = (p("friction_patch", "x0", 0.0), p("friction_patch", "x1", 0.0),
                      p("friction_patch", "factor", 1.0))
        self.robot, self.motor = robot, motor
        self.V0, self.w0 = motor["supply_v"], motor["no_load_rad_s"]
        self.stall, self.stall_a = motor["stall_nm"], motor["stall_a"]
        self.tau_e = inductance_h * self.stall_a / self.V0  # L / R
        self.model = mujoco.MjModel.from_xml_string(self.xml())
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._gid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in ("wheel_r", "wheel_l")]
        self._gcaster = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "caster")
        self._bid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("wheel_r", "wheel_l")]
        self.reset()

    # ------------------------------------------------------------------------------ model
    def xml(self) -> str:
        """The MJCF text of the model (from the table and the effects)."""
        R = self.robot
        r, b, d, e, h = self.r, self.b, R["d"], R["e"], self.h
        I_rz, I_wz, I_wy = R["I_rz"], R["I_wz"], R["I_wy"]
        g = R["g"]
        rc = CASTER_RADIUS_FRACTION * r
        # wheel body: I_wz about x and z, I_wz about the axle (a valid inertia); the rest of
        # I_wy is the hinge's armature (rotor and gearbox reflected through the gear)
        i_axle = min(I_wz, I_wy) if I_wz > 0 else I_wy
        armature = I_wy - i_axle
        iw = max(I_wz, 1e-9)
        gx, gz = -g * math.sin(self.slope), -g * math.cos(self.slope)
        sr, ir = CONTACT["solref"], CONTACT["solimp"]
        caster = (f'condim="3" friction="{self.mu_caster:.9g} 0 0"' if self.mu_caster > 0
                  else 'condim="1"')

        def wheel(name, side, phase):
            dl = self.ecc * r  # an eccentric wheel: the sphere off the axle
            off = f"{-dl * math.sin(phase):.9g} 0 {-dl * math.cos(phase):.9g}"
            return f"""
      <body name="wheel_{name}" pos="0 {side * b:.9g} 0">
        <joint name="axle_{name}" type="hinge" axis="0 1 0" armature="{armature:.9g}"
               damping="{self.c_visc:.9g}" frictionloss="{self.t_coul:.9g}"/>
        <inertial pos="0 0 0" mass="{m_w:.9g}" diaginertia="{iw:.9g} {i_axle:.9g} {iw:.9g}"/>
        <geom name="wheel_{name}" type="sphere" size="{r:.9g}" pos="{off}" contype="2"
              conaffinity="1" condim="3" friction="{self.mu_s:.9g} 0 0"/>
      </body>"""
        m_c = R["m_r"] + self.payload
        m_w, I_cz = R["m_w"], I_rz
        if self.lumped:  # the wheels' mass at c (lib/slipmodel's m_t and I_t)
            m_c, I_cz, m_w = m_c + 2 * R["m_w"], I_rz + 2 * R["m_w"] * b * b, 1e-6
        return f"""<mujoco model="ddrobot">
  <option timestep="{self.dt:.9g}" gravity="{gx:.9g} 0 {gz:.9g}" cone="elliptic"
          impratio="{CONTACT['impratio']:.9g}" integrator="implicitfast"/>
  <default><geom solref="{sr[0]:.9g} {sr[1]:.9g}" solimp="{ir[0]:.9g} {ir[1]:.9g} {ir[2]:.9g}"/></default>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1" contype="1" conaffinity="2" condim="1" friction="0 0 0"/>
    <body name="chassis" pos="0 0 {r:.9g}">
      <freejoint name="base"/>
      <inertial pos="{d:.9g} 0 {h - r:.9g}" mass="{m_c:.9g}"
                diaginertia="{0.55 * I_cz:.9g} {0.55 * I_cz:.9g} {I_cz:.9g}"/>
      <geom name="caster" type="sphere" size="{rc:.9g}" pos="{d + e:.9g} 0 {rc - r:.9g}"
            contype="2" conaffinity="1" {caster}/>{wheel("r", -1, self.ecc_phase[0])}{wheel("l", 1, self.ecc_phase[1])}
    </body>
  </worldbody>
  <actuator>
    <motor name="motor_r" joint="axle_r" gear="1"/>
    <motor name="motor_l" joint="axle_l" gear="1"/>
  </actuator>
</mujoco>"""

    # ------------------------------------------------------------------------------ state
    def reset(self) -> None:
        """At rest with o at the origin facing +x, after the contacts have taken the load."""
        mj, m, dd = self._mj, self.model, self.data
        mj.mj_resetData(m, dd)
        for gid in self._gid:
            m.geom_friction[gid, 0] = self.mu_s
        n = int(round(SETTLE_S / self.dt))
        for _ in range(n):  # wheels held still while settling
            dd.qvel[6:8] = 0.0
            mj.mj_step(m, dd)
        dd.qpos[0:2] = 0.0
        w, x, y, z = dd.qpos[3:7]
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        # remove the yaw, keep the small settled pitch and roll
        cy, sy = math.cos(-yaw / 2), math.sin(-yaw / 2)
        dd.qpos[3:7] = (cy * w - sy * z, cy * x - sy * y, cy * y + sy * x, cy * z + sy * w)
        dd.qpos[7:9] = 0.0
        dd.qvel[:] = 0.0
        dd.time = 0.0
        mj.mj_forward(m, dd)
        self.sliding = [False, False]
        self.slip_speed = [0.0, 0.0]
        self.i1 = [0.0, 0.0]   # current after the inductance
        self.i2 = [0.0, 0.0]   # current after the motor lag
        self.charge_as = 0.0
        self.v_batt = self.V0
        self.phi = 0.0
        self._yaw_last = 0.0
        self._duties: deque = deque()
        self._u = (0.0, 0.0)
        self.tau = [0.0, 0.0]
        self._res_buf = np.zeros(6)
        self._nf_count, self._nf = FORCES_EVERY, (0.0, 0.0, 0.0)
        self._cache()

    def _mu(self, i: int, x_contact: float) -> float:
        if not self.sliding[i]:
            mu = self.mu_s
        else:
            mu = self.mu_k
            if self.stribeck:
                s = self.slip_speed[i] / self.v_s
                mu = min(self.mu_s, self.mu_k + (self.mu_k0 - self.mu_k) * math.exp(-s * s))
        x0, x1, f = self.patch
        if x1 > x0 and x0 <= x_contact <= x1:
            mu *= f
        return mu

    def _applied_duty(self, t: float, u_r: float, u_l: float) -> tuple[float, float]:
        if self.delay <= 0.0:
            return u_r, u_l
        q = self._duties
        if not q or q[-1][1:] != (u_r, u_l):
            q.append((t, u_r, u_l))
        t_cmd = t - self.delay + 1e-12  # the command in force now was given at or before this
        while len(q) > 1 and q[1][0] <= t_cmd:
            q.popleft()
        if q[0][0] <= t_cmd:
            self._u = q[0][1:]
        return self._u

    def _cache(self) -> None:
        """Constants and array views of the step (the step runs from Python every 0.2 ms)."""
        mj, m, dd = self._mj, self.model, self.data
        self._c = {"kt": self.stall / self.stall_a, "ke": self.ke_ratio * self.V0 / self.w0,
                   "gain": (math.sqrt(self.asym), 1.0 / math.sqrt(self.asym)),
                   "a_e": 1.0 - math.exp(-self.dt / self.tau_e) if self.tau_e > 0 else 1.0,
                   "a_l": 1.0 - math.exp(-self.dt / self.lag) if self.lag > 0 else 1.0,
                   "geom": mj.mjtObj.mjOBJ_GEOM}
        self._qpos, self._qvel, self._ctrl = dd.qpos, dd.qvel, dd.ctrl
        self._gf, self._xpos = m.geom_friction, dd.xpos
        self._mu_set = [None, None]

    def step(self, t: float, u_r: float, u_l: float) -> None:
        """Advance one step (``dt``) with the duties ``u_r``, ``u_l`` applied by the board at
        ``t``."""
        mj, m, dd, c = self._mj, self.model, self.data, self._c
        ur, ul = self._applied_duty(t, u_r, u_l)
        # ---- drive: battery, driver drop, deadband -> armature current -> lags -> torque
        V0, ia, qvel = self.V0, self.stall_a, self._qvel
        v_avail = max(0.0, self.v_batt - self.v_drop)
        i1, i2, tau = self.i1, self.i2, self.tau
        for i, u in ((0, ur), (1, ul)):
            V = u * v_avail
            if self.v_dead > 0.0:
                V = math.copysign(max(abs(V) - self.v_dead, 0.0), V)
            i_ss = ia * (V - c["ke"] * float(qvel[6 + i])) / V0
            i_ss = -ia if i_ss < -ia else ia if i_ss > ia else i_ss
            i1[i] += c["a_e"] * (i_ss - i1[i])     # inductance (a_e = 1 without)
            i2[i] += c["a_l"] * (i1[i] - i2[i])    # motor lag (a_l = 1 without)
            tau[i] = c["kt"] * i2[i] * c["gain"][i]
        ctrl = self._ctrl
        ctrl[0] = tau[0]
        ctrl[1] = tau[1]
        if self.r_int > 0.0 or self.v_per_as > 0.0:
            i_draw = abs(i2[0]) + abs(i2[1])
            self.charge_as += i_draw * self.dt
            self.v_batt = V0 - self.r_int * i_draw - self.v_per_as * self.charge_as
        # ---- friction by slip state
        for i in (0, 1):
            mu = self._mu(i, float(self._xpos[self._bid[i], 0]))
            if mu != self._mu_set[i]:
                self._gf[self._gid[i], 0] = mu
                self._mu_set[i] = mu
        mj.mj_step(m, dd)
        # ---- slip state of each wheel's contact point (under the sphere's centre)
        res, r = self._res_buf, self.r
        for i in (0, 1):
            mj.mj_objectVelocity(m, dd, c["geom"], self._gid[i], res, 0)
            s = math.hypot(res[3] - r * res[1], res[4] + r * res[0])
            self.slip_speed[i] = s
            self.sliding[i] = s > (SLIP_OFF_M_S if self.sliding[i] else SLIP_ON_M_S)
        w, x, y, z = self._qpos[3:7].tolist()
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        dy = yaw - self._yaw_last
        self.phi += dy - 2 * math.pi * round(dy / (2 * math.pi))
        self._yaw_last = yaw

    def plant_callback(self):
        """The ctypes function ``sim/truth``'s ``tr_set_plant`` calls once per step; keep it
        alive while the recorder runs. An exception stops the run and is kept in
        :attr:`error`."""
        import ctypes
        proto = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                 ctypes.c_double, ctypes.c_double, ctypes.POINTER(ctypes.c_double))
        self.error = None
        views: dict = {}
        n_state = len(self.state())
        self._nf_count = FORCES_EVERY

        def step(_user, t, dt, u_r, u_l, out):
            try:
                if abs(dt - self.dt) > 1e-12:
                    raise ValueError(f"the recorder steps {dt:g} s, the engine {self.dt:g} s")
                self.step(t, u_r, u_l)
                addr = ctypes.cast(out, ctypes.c_void_p).value
                view = views.get(addr)
                if view is None:  # the recorder's buffer: one address for a whole run
                    view = views[addr] = np.ctypeslib.as_array(out, shape=(n_state,))
                view[:] = self.state()
                return 0
            except Exception as exc:  # noqa: BLE001 - handed back to the caller of tr_run
                self.error = exc
                return 1
        return proto(step)

    def normal_forces(self) -> tuple[float, float, float]:
        """Normal contact forces of the right wheel, left wheel and caster (N)."""
        import numpy as np
        mj, m, dd = self._mj, self.model, self.data
        out = {self._gid[0]: 0.0, self._gid[1]: 0.0, self._gcaster: 0.0}
        f = np.zeros(6)
        for k in range(dd.ncon):
            c = dd.contact[k]
            for gid in (c.geom1, c.geom2):
                if gid in out:
                    mj.mj_contactForce(m, dd, k, f)
                    out[gid] += f[0]
        return out[self._gid[0]], out[self._gid[1]], out[self._gcaster]

    def state(self) -> list[float]:
        """``sim/truth``'s plant state (``tr_plant_state_name``): pose of o, wheel angles and
        speeds, slip flags, delivered torques, normal forces (evaluated every
        :data:`FORCES_EVERY` steps), battery, currents."""
        self._nf_count += 1
        if self._nf_count >= FORCES_EVERY:
            self._nf, self._nf_count = self.normal_forces(), 0
        n = self._nf
        x, y = self._qpos[0:2].tolist()
        th_r, th_l = self._qpos[7:9].tolist()
        w_r, w_l = self._qvel[6:8].tolist()
        return [x, y, self.phi, th_r, th_l, w_r, w_l,
                1.0 if self.sliding[0] else 0.0, 1.0 if self.sliding[1] else 0.0,
                self.tau[0], self.tau[1], n[0], n[1], n[2], self.v_batt, self.i2[0], self.i2[1]]
