"""Part 1 of the main job: II.6.1-II.6.3 on the nominal model, figures, results.json and the
table against the thesis (host_tools.demo.table)."""
from __future__ import annotations

import json
import os

import numpy as np

from host_tools.demo.common import _plt, _total_mass_kg, ACCEL_TIME_S, CONTROLLERS, THESIS
from host_tools.demo.ii62 import _gain_sensitivity, _ii62_run
from host_tools.demo.ii63 import (_ii63_budget, _ii63_floor, _ii63_parameter_change, _ii63_run,
                                  _mu_s_for_peak)
from host_tools.demo.table import _thesis_table, _yn
from host_tools.demo.utilisation import _utilisation, _utilisation_fil


def thesis_reproduction(out_dir: str, log=print, with_fil: bool = True) -> dict:
    """Run II.6.1-II.6.3 on the nominal model; write figures, table and results.json."""
    from host_tools import _native
    plt = _plt()
    os.makedirs(out_dir, exist_ok=True)
    res: dict = {}
    plant = _native.Plant()
    tau_max = plant.tau_max()[0]
    res["tau_max_nm"] = tau_max
    r_wheel = plant.get("robot.r")
    # Torque per wheel that rolling at wheel acceleration alpha needs on a straight line:
    # (I_wy + m_t r^2 / 2) alpha (the wheel's spin plus half the body), and the largest alpha
    # that tau_max allows. Both from lib/slipmodel's parameters.
    m_t = _total_mass_kg(plant)
    j_roll = plant.get("robot.I_wy") + 0.5 * m_t * r_wheel ** 2
    res["rolling_inertia_kgm2"] = j_roll
    res["alpha_no_slip_rad_s2"] = tau_max / j_roll

    # ---- II.6.1: constant torque on both wheels, slip model vs pure rolling (mu -> large)
    rolling = _native.Plant()
    rolling.set("robot.mu_s", 100.0)
    rolling.set("robot.mu_k", 100.0)
    T1 = 2.0
    t = np.round(np.arange(0.0, T1 + 1e-9, 0.005), 9)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=False)
    res["ii61"] = []
    for ax, tau in zip(axes, (0.09, 0.1, 0.3)):
        u = np.full(t.size, tau)
        s = plant.simulate(t, u, u, "torque")
        p = rolling.simulate(t, u, u, "torque")
        slipped = bool((s["slip_r"] > 0).any() or (s["slip_l"] > 0).any())
        row = {"tau_nm": tau, "slip": slipped, "x_slip_m": float(s["x_m"][-1]),
               "x_rolling_m": float(p["x_m"][-1]), "t_s": T1,
               "wheel_path_m": float(r_wheel * 0.5 * (s["theta_r_rad"][-1] + s["theta_l_rad"][-1]))}
        res["ii61"].append(row)
        ax.plot(t, p["x_m"], "k--", label="pure rolling (mu = 100)")
        ax.plot(t, s["x_m"], "C3", label="slip model")
        ax.plot(t, r_wheel * 0.5 * (s["theta_r_rad"] + s["theta_l_rad"]), "C0:",
                label="slip model: wheel path r*theta")
        ax.set_title(f"tau = {tau} N m ({'slips' if slipped else 'no slip'})")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("x [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"II.6.1 torque steps (Figs. II.13-II.15); tau_max = {tau_max:.4f} N m")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "ii61_torque_steps.png"), dpi=110)
    plt.close(fig)
    log(f"  II.6.1 done: tau_max {tau_max:.4f} N m")

    # ---- II.6.2: straight profiles, clamp off, both controllers; with an ideal torque source
    # (as the thesis's Simulink model) and through the motor (as the robot)
    T2 = 3.0
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    for i, (cname, cid) in enumerate(CONTROLLERS.items()):
        ctl_res = res.setdefault(cname, {})
        ctl_res["ii62"], ctl_res["ii62_motor"] = {}, {}
        for j, alpha in enumerate((44.0, 48.0, 72.0)):
            for actuator, key in (("torque", "ii62"), ("duty", "ii62_motor")):
                row, r = _ii62_run(alpha, r_wheel, {"controller": cid}, actuator, T2)
                row["tau_needed_nm"] = j_roll * alpha
                ctl_res[key][f"{alpha:g}"] = row
                if actuator != "torque":
                    continue
                ax = axes[i, j]
                ax.plot(r["t_s"], np.minimum(r["t_s"], ACCEL_TIME_S) * alpha, "k--",
                        label="reference wheel speed")
                ax.plot(r["t_s"], r["dtheta_r_rad_s"], "C3", label="true wheel speed (right)")
                ax.plot(r["t_s"], r["v_m_s"] / r_wheel, "C0:", label="body speed / r")
                ax.set_title(f"{cname}: {alpha:.0f} rad/s^2: {_yn(row['slipped'])}, "
                             f"peak {row['peak_tau_nm']:.3f} N m", fontsize=9)
                ax.set_xlabel("t [s]")
                ax.set_ylabel("rad/s")
                ax.set_xlim(0.0, 1.5)
                ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("II.6.2 velocity profiles, clamp off, ideal torque source (Figs. II.16-II.21): "
                 "thesis controller (top), improved (bottom)")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "ii62_profiles.png"), dpi=110)
    plt.close(fig)
    res["ii62_gain_sensitivity"] = _gain_sensitivity(r_wheel, T2)
    log("  II.6.2 done")

    # ---- II.6.3: 72 rad/s^2, clamp on vs off, both controllers; through the motor (as the
    # robot) and with an ideal torque source (as the thesis's Simulink model)
    T3 = 20.0
    fig, axes = plt.subplots(1, 3, figsize=(16, 4))
    for cname, cid in CONTROLLERS.items():
        ii63 = res[cname]["ii63"] = {}
        for actuator in ("duty", "torque"):
            for clamp in (False, True):
                name = ("clamp_on" if clamp else "clamp_off") + ("" if actuator == "duty" else "_torque_source")
                entry, r, err = _ii63_run(r_wheel, {"controller": cid}, clamp, actuator, T3)
                ii63[name] = entry
                style = ("-" if cname == "improved" else "--")
                col = {("duty", False): "C3", ("duty", True): "C2",
                       ("torque", False): "C1", ("torque", True): "C0"}[(actuator, clamp)]
                label = f"{cname}, clamp {'on' if clamp else 'off'}"
                ax = axes[0] if actuator == "duty" else axes[1]
                ax.plot(r["t_s"], err, col, ls=style, label=label)
                if actuator == "duty":
                    axes[2].step(r["t_s"], r["tau_cmd_r"], col, ls=style, where="post", label=label)
    floor = _ii63_floor(plant, 72.0 * r_wheel, ACCEL_TIME_S, THESIS["ii63_max_err_on_m"])
    res["ii63_floor_m"] = floor["floor_m"]
    res["ii63_floor"] = floor
    for ax in axes[:2]:
        ax.axhline(floor["floor_m"], color="k", ls=":", label="floor for any controller")
    axes[2].axhline(tau_max, color="k", ls=":", label="tau_max (II.51)")
    axes[2].set_xlim(0.0, 3.0)
    axes[0].set_title("|p - p_ref|, through the datasheet motor (Figs. II.23, II.25)", fontsize=9)
    axes[1].set_title("|p - p_ref|, ideal torque source", fontsize=9)
    axes[2].set_title("torque command, right wheel, motor (Fig. II.24)", fontsize=9)
    for ax in axes:
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("m")
    axes[1].set_ylabel("m")
    axes[2].set_ylabel("N m")
    fig.suptitle("II.6.3 closed loop at 72 rad/s^2 with and without the tau_max clamp "
                 "(dashed: thesis controller, solid: improved)")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "ii63_clamp.png"), dpi=110)
    plt.close(fig)
    by_ctl = {c: _utilisation(r_wheel, j_roll, tau_max, {"controller": cid}) for c, cid in CONTROLLERS.items()}
    res["ii63_budget"] = _ii63_budget(floor, res["improved"]["ii63"], tau_max, by_ctl)
    res["ii63_parameter_change"] = _ii63_parameter_change(floor, r_wheel)
    res["ii63_parameter_change"]["mu_s_for_target_run"] = _mu_s_for_peak(
        r_wheel, THESIS["ii63_max_err_on_m"], "improved", plant.get("robot.mu_s"), 0.6)
    fil_u = _utilisation_fil(tau_max, r_wheel, log) if with_fil else {"utilisation": None, "error": "skipped"}
    res["torque_utilisation"] = {"plant": by_ctl["improved"]["utilisation"], "fil": fil_u["utilisation"],
                                 "controller": "improved", "plant_by_controller": by_ctl, "fil_detail": fil_u}
    log("  II.6.3 done")

    with open(os.path.join(out_dir, "results.json"), "w") as fh:
        json.dump(res, fh, indent=2)
    with open(os.path.join(out_dir, "README.md"), "w") as fh:
        fh.write(_thesis_table(res))
    return res
