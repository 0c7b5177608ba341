#if !defined(__AVR__)
#include <slipmodel/plant.h>

#include <math.h>

#include <slipmodel/motor.h>

namespace slip {

namespace {

enum { kV = 0, kW, kOm, kTr, kTl, kN };  // generalized velocity u = (v, w, omega, dth_r, dth_l)

// Inverse mass matrix of the 5 velocities (see README): block-diagonal with
// [[m, 0, 0], [0, m, m d], [0, m d, I_o]] and diag(I_wy, I_wy).
struct InvMass {
  double inv_m, a11, a12, a22, inv_iw;
  void apply(const double q[kN], double out[kN]) const {
    out[kV] = inv_m * q[kV];
    out[kW] = a11 * q[kW] + a12 * q[kOm];
    out[kOm] = a12 * q[kW] + a22 * q[kOm];
    out[kTr] = inv_iw * q[kTr];
    out[kTl] = inv_iw * q[kTl];
  }
};

struct Mass {
  double m, md, io, iw;
  double energy2(const double u[kN]) const {  // u^T M u
    return m * (u[kV] * u[kV] + u[kW] * u[kW]) + 2.0 * md * u[kW] * u[kOm] +
           io * u[kOm] * u[kOm] + iw * (u[kTr] * u[kTr] + u[kTl] * u[kTl]);
  }
};

double dot(const double a[kN], const double b[kN]) {
  double s = 0.0;
  for (int i = 0; i < kN; ++i) s += a[i] * b[i];
  return s;
}

// Solves K x = rhs (n <= 3) by Gaussian elimination with partial pivoting. Returns false if singular.
bool solve_small(int n, double K[3][3], double rhs[3], double x[3]) {
  for (int c = 0; c < n; ++c) {
    int piv = c;
    for (int r = c + 1; r < n; ++r)
      if (fabs(K[r][c]) > fabs(K[piv][c])) piv = r;
    if (fabs(K[piv][c]) < 1e-300) return false;
    if (piv != c) {
      for (int k = 0; k < n; ++k) { const double t = K[c][k]; K[c][k] = K[piv][k]; K[piv][k] = t; }
      const double t = rhs[c]; rhs[c] = rhs[piv]; rhs[piv] = t;
    }
    for (int r = c + 1; r < n; ++r) {
      const double f = K[r][c] / K[c][c];
      for (int k = c; k < n; ++k) K[r][k] -= f * K[c][k];
      rhs[r] -= f * rhs[c];
    }
  }
  for (int r = n - 1; r >= 0; --r) {
    double s = rhs[r];
    for (int k = r + 1; k < n; ++k) s -= K[r][k] * x[k];
    x[r] = s / K[r][r];
  }
  return true;
}

double finite_or_zero(double x) { return isfinite(x) ? x : 0.0; }

}  // namespace

Plant::Plant(const RobotParams& robot, const MotorParams& motor) : robot_(robot), motor_(motor) {
  reset(0.0, 0.0, 0.0);
}

void Plant::reset(double x_m, double y_m, double phi_rad) {
  s_ = PlantState();
  s_.x_m = x_m;
  s_.y_m = y_m;
  s_.phi_rad = phi_rad;
  stuck_[0] = stuck_[1] = true;
  for (int i = 0; i < 2; ++i) { slip_dir_[i][0] = 1.0; slip_dir_[i][1] = 0.0; }
  lat_force_prev_n_ = 0.0;
  ax_prev_m_s2_ = 0.0;
  spin_acc_prev_rad_s2_ = 0.0;
  tau_lag_[0] = tau_lag_[1] = 0.0;
  history_.clear();
  const NormalForces n = static_normal_forces();
  s_.N_r = n.N_r;
  s_.N_l = n.N_l;
  s_.N_c = n.N_c;
}

void Plant::set_velocity(double v_m_s, double w_m_s, double omega_rad_s, double dtheta_r_rad_s,
                         double dtheta_l_rad_s) {
  s_.v_m_s = v_m_s;
  s_.w_m_s = w_m_s;
  s_.omega_rad_s = omega_rad_s;
  s_.dtheta_r_rad_s = dtheta_r_rad_s;
  s_.dtheta_l_rad_s = dtheta_l_rad_s;
  const double b = fx_.on(kTrackWidth) ? fx_.p[kTrackWidth][0] : robot_.b;
  const double r = fx_.on(kWheelRadius) ? fx_.p[kWheelRadius][0] : robot_.r;
  const double sr = v_m_s + b * omega_rad_s - r * dtheta_r_rad_s;
  const double sl = v_m_s - b * omega_rad_s - r * dtheta_l_rad_s;
  stuck_[0] = sqrt(sr * sr + w_m_s * w_m_s) < 1e-9;
  stuck_[1] = sqrt(sl * sl + w_m_s * w_m_s) < 1e-9;
  s_.slipping_r = !stuck_[0];
  s_.slipping_l = !stuck_[1];
}

void Plant::set_time(double t_s) {
  // Only a real jump back in time invalidates the delay line. Re-aligning the clock after summed
  // steps (sm_simulate does it at every input sample) moves it by rounding only, ~1e-15 s.
  const double kBackJumpS = 1e-6;
  if (t_s < s_.t_s - kBackJumpS) history_.clear();
  s_.t_s = t_s;
}

bool Plant::set_spin_share(double share) {
  if (!(share >= 0.0 && share <= 1.0)) return false;
  spin_share_ = share;
  return true;
}

void Plant::set_effect(EffectId id, bool on, double p0, double p1) {
  if (id < 0 || id >= kEffectCount) return;
  fx_.enabled[id] = on;
  fx_.p[id][0] = p0;
  if (effect_info(id).param_count > 1) fx_.p[id][1] = p1;
}

double Plant::kinetic_energy_j() const {
  const RobotParams& p = robot_;
  const Mass M{p.m_t(), p.m_t() * p.d, p.I_o(), p.I_wy};
  const double u[kN] = {s_.v_m_s, s_.w_m_s, s_.omega_rad_s, s_.dtheta_r_rad_s, s_.dtheta_l_rad_s};
  return 0.5 * M.energy2(u);
}

NormalForces Plant::static_normal_forces() const {
  RobotParams p = robot_;
  if (fx_.on(kFloorSlope)) p.g = robot_.g * cos(fx_.p[kFloorSlope][0]);
  if (fx_.on(kTrackWidth)) p.b = fx_.p[kTrackWidth][0];
  return normal_forces(p, 0.0);
}

double Plant::tau_max_nm(int wheel) const {
  RobotParams p = robot_;
  if (fx_.on(kFrictionCoefficient)) p.mu_s = fx_.p[kFrictionCoefficient][0];
  if (fx_.on(kWheelRadius)) p.r = fx_.p[kWheelRadius][0];
  const NormalForces n = static_normal_forces();
  return tau_max(p, wheel == 0 ? n.N_r : n.N_l);
}

void Plant::step_torque(double tau_r_nm, double tau_l_nm, double dt_s) {
  step(0, tau_r_nm, tau_l_nm, dt_s);
}

void Plant::step_duty(double u_r, double u_l, double dt_s) { step(1, u_r, u_l, dt_s); }

double Plant::current_a(int wheel) const {
  double tau = wheel == 0 ? s_.tau_r_nm : s_.tau_l_nm;
  if (fx_.on(kMotorGainAsymmetry) && fx_.p[kMotorGainAsymmetry][0] > 0.0) {
    const double k = sqrt(fx_.p[kMotorGainAsymmetry][0]);
    tau = wheel == 0 ? tau / k : tau * k;
  }
  return motor_current_a(motor_, tau);
}

void Plant::step(int mode, double in_r, double in_l, double dt) {
  if (!(dt > 0.0) || !isfinite(dt)) return;
  in_r = finite_or_zero(in_r);
  in_l = finite_or_zero(in_l);
  const RobotParams& p = robot_;
  const double m = p.m_t();
  const double d = p.d;
  const double r = fx_.on(kWheelRadius) ? fx_.p[kWheelRadius][0] : p.r;
  const double b = fx_.on(kTrackWidth) ? fx_.p[kTrackWidth][0] : p.b;
  const double mu_s = fx_.on(kFrictionCoefficient) ? fx_.p[kFrictionCoefficient][0] : p.mu_s;
  // Kinetic friction never exceeds static: a larger mu_k would make a wheel that breaks loose
  // stick again at once (chatter). mu_k > mu_s is therefore used as mu_k = mu_s.
  double mu_k = fx_.on(kFrictionCoefficient) ? fx_.p[kFrictionCoefficient][1] : p.mu_k;
  if (mu_k > mu_s) mu_k = mu_s;

  // ---- 1. command pipeline -------------------------------------------------------------
  double cmd_r = in_r, cmd_l = in_l;
  if (fx_.on(kActuationDelay) && fx_.p[kActuationDelay][0] > 0.0) {
    history_.push_back(Cmd{s_.t_s, in_r, in_l});
    const double t_use = s_.t_s - fx_.p[kActuationDelay][0] + 1e-12;
    while (history_.size() > 1 && history_[1].t_s <= t_use) history_.pop_front();
    if (history_.front().t_s <= t_use) {
      cmd_r = history_.front().r;
      cmd_l = history_.front().l;
    } else {
      cmd_r = cmd_l = 0.0;  // nothing commanded that long ago
    }
  }
  double tau_r = cmd_r, tau_l = cmd_l;
  if (mode == 1) {
    MotorImperfections mi;
    mi.ke_ratio = fx_.get(kMotorBackEmf, 0);
    mi.drop_v = fx_.get(kDriverVoltageDrop, 0);
    mi.deadband_v = fx_.get(kDeadband, 0);
    tau_r = motor_torque_nm(motor_, cmd_r, s_.dtheta_r_rad_s, mi);
    tau_l = motor_torque_nm(motor_, cmd_l, s_.dtheta_l_rad_s, mi);
  }
  if (fx_.on(kMotorGainAsymmetry) && fx_.p[kMotorGainAsymmetry][0] > 0.0) {
    const double k = sqrt(fx_.p[kMotorGainAsymmetry][0]);
    tau_r *= k;
    tau_l /= k;
  }
  if (fx_.on(kMotorLag) && fx_.p[kMotorLag][0] > 0.0) {
    const double a = 1.0 - exp(-dt / fx_.p[kMotorLag][0]);
    tau_lag_[0] += a * (tau_r - tau_lag_[0]);
    tau_lag_[1] += a * (tau_l - tau_lag_[1]);
    tau_r = tau_lag_[0];
    tau_l = tau_lag_[1];
  } else {
    tau_lag_[0] = tau_r;
    tau_lag_[1] = tau_l;
  }

  // ---- 2. normal forces ----------------------------------------------------------------
  const double slope = fx_.on(kFloorSlope) ? fx_.p[kFloorSlope][0] : 0.0;
  const double mg = m * p.g * cos(slope);
  double Nc = mg * d / (d + p.e);                                       // II.29
  if (fx_.on(kLoadTransfer))  // pitch balance about c (README, "Load transfer and spin-up")
    Nc -= (m * ax_prev_m_s2_ * fx_.p[kLoadTransfer][0] +
           spin_share_ * p.I_wy * spin_acc_prev_rad_s2_) / (d + p.e);
  if (Nc < 0.0) Nc = 0.0;
  if (Nc > mg) Nc = mg;
  const double Nw = mg - Nc;                                             // II.27
  const double transfer = p.h * lat_force_prev_n_ / (2.0 * b);          // II.28
  double N[2] = {0.5 * Nw + transfer, 0.5 * Nw - transfer};
  if (N[0] < 0.0) { N[0] = 0.0; N[1] = Nw; }
  if (N[1] < 0.0) { N[1] = 0.0; N[0] = Nw; }

  // ---- 3. velocities -------------------------------------------------------------------
  const double it = p.I_t();
  const double io = it + m * d * d;
  const Mass M{m, m * d, io, p.I_wy};
  InvMass A;
  A.inv_m = 1.0 / m;
  A.a11 = io / (m * it);
  A.a12 = -d / it;
  A.a22 = 1.0 / it;
  A.inv_iw = 1.0 / p.I_wy;

  const double u0[kN] = {s_.v_m_s, s_.w_m_s, s_.omega_rad_s, s_.dtheta_r_rad_s, s_.dtheta_l_rad_s};
  const double v = u0[kV], w = u0[kW], om = u0[kOm];

  // 3a. Workless velocity-product (centripetal/Coriolis) forces, then restore the kinetic
  // energy they cannot change (explicit Euler would add O(dt^2) energy per step).
  double u1[kN];
  {
    const double g[kN] = {m * (om * w + om * om * d), -m * om * v, -m * d * om * v, 0.0, 0.0};
    double ag[kN];
    A.apply(g, ag);
    for (int i = 0; i < kN; ++i) u1[i] = u0[i] + dt * ag[i];
    // Only the body block (v, w, omega) is touched by g, and M is block-diagonal between the body
    // and the wheels, so the body block alone is scaled back to its energy.
    const double w0[kN] = {u0[kV], u0[kW], u0[kOm], 0.0, 0.0};
    const double w1[kN] = {u1[kV], u1[kW], u1[kOm], 0.0, 0.0};
    const double e0 = M.energy2(w0), e1 = M.energy2(w1);
    if (e1 > 0.0) {
      const double k = sqrt(e0 / e1);
      u1[kV] *= k;
      u1[kW] *= k;
      u1[kOm] *= k;
    }
  }

  // 3b. Applied forces: motor torques, axle friction, caster drag, floor slope.
  double Q[kN] = {0.0, 0.0, 0.0, tau_r, tau_l};
  if (fx_.on(kAxleViscous)) {
    Q[kTr] -= fx_.p[kAxleViscous][0] * u0[kTr];
    Q[kTl] -= fx_.p[kAxleViscous][0] * u0[kTl];
  }
  if (fx_.on(kAxleCoulomb) && fx_.p[kAxleCoulomb][0] > 0.0) {
    const double T = fx_.p[kAxleCoulomb][0];
    const double band = 2.0 * T * dt * A.inv_iw;  // regularisation band, rad/s
    for (int i = 0; i < 2; ++i) {
      double x = u0[kTr + i] / band;
      x = x > 1.0 ? 1.0 : (x < -1.0 ? -1.0 : x);
      Q[kTr + i] -= T * x;
    }
  }
  double Fcx = 0.0;
  if (fx_.on(kCasterDrag) && fx_.p[kCasterDrag][0] > 0.0 && Nc > 0.0) {
    const double lc = d + p.e;  // caster contact ahead of o
    const double cx = v, cy = w + lc * om;
    const double cmag = sqrt(cx * cx + cy * cy);
    const double f = fx_.p[kCasterDrag][0] * Nc;
    const double k = A.inv_m + A.a11 + 2.0 * lc * A.a12 + lc * lc * A.a22;  // trace(J A J^T)
    const double band = 2.0 * f * dt * k;
    const double den = cmag > band ? cmag : band;
    if (den > 0.0) {
      const double fx = -f * cx / den, fy = -f * cy / den;
      Q[kV] += fx;
      Q[kW] += fy;
      Q[kOm] += lc * fy;
      Fcx = fx;
    }
  }
  double Fsx = 0.0;
  if (slope != 0.0) {
    const double fw = -m * p.g * sin(slope);  // along world +x
    Fsx = fw * cos(s_.phi_rad);
    const double Fsy = -fw * sin(s_.phi_rad);
    Q[kV] += Fsx;
    Q[kW] += Fsy;
    Q[kOm] += d * Fsy;
  }
  double ubase[kN];
  {
    double aq[kN];
    A.apply(Q, aq);
    for (int i = 0; i < kN; ++i) ubase[i] = u1[i] + dt * aq[i];
  }

  // 3c. Contacts. Jacobian rows: longitudinal slip of wheel i, and the shared lateral slip w.
  const double jl[2][kN] = {{1.0, 0.0, b, -r, 0.0}, {1.0, 0.0, -b, 0.0, -r}};
  const double jw[kN] = {0.0, 1.0, 0.0, 0.0, 0.0};
  double s0[2][2];  // slip velocity (long, lat) of each contact at the start of the step
  for (int i = 0; i < 2; ++i) { s0[i][0] = dot(jl[i], u0); s0[i][1] = w; }

  bool stuck[2] = {stuck_[0], stuck_[1]};
  bool released[2] = {false, false};
  double f[2][2] = {{0.0, 0.0}, {0.0, 0.0}};  // contact force (long, lat) on each wheel
  double u[kN];
  const double stribeck_k0 = fx_.on(kStribeck) ? fx_.p[kStribeck][0] : mu_k;
  const double stribeck_vs = fx_.on(kStribeck) ? fx_.p[kStribeck][1] : 1.0;
  for (int iter = 0; iter < 8; ++iter) {
    // Kinetic friction on slipping wheels.
    double Qc[kN] = {0.0, 0.0, 0.0, 0.0, 0.0};
    for (int i = 0; i < 2; ++i) {
      if (stuck[i]) continue;
      const double smag = sqrt(s0[i][0] * s0[i][0] + s0[i][1] * s0[i][1]);
      double dir0, dir1, mu = mu_k;
      if (smag > 1e-12 && !released[i]) {
        dir0 = -s0[i][0] / smag;
        dir1 = -s0[i][1] / smag;
      } else {
        dir0 = slip_dir_[i][0];
        dir1 = slip_dir_[i][1];
      }
      if (fx_.on(kStribeck) && stribeck_vs > 0.0) {
        const double x = (released[i] ? 0.0 : smag) / stribeck_vs;
        mu = mu_k + (stribeck_k0 - mu_k) * exp(-x * x);
        if (mu > mu_s) mu = mu_s;  // kinetic never above static: no stick/slip chatter
      }
      f[i][0] = mu * N[i] * dir0;
      f[i][1] = mu * N[i] * dir1;
      for (int k = 0; k < kN; ++k) Qc[k] += jl[i][k] * f[i][0] + jw[k] * f[i][1];
    }
    double ufree[kN], aq[kN];
    A.apply(Qc, aq);
    for (int k = 0; k < kN; ++k) ufree[k] = ubase[k] + dt * aq[k];

    // Constraints of stuck wheels: J u+ = 0.
    const double* rows[3];
    int nr = 0;
    for (int i = 0; i < 2; ++i)
      if (stuck[i]) rows[nr++] = jl[i];
    const bool any_stuck = stuck[0] || stuck[1];
    if (any_stuck) rows[nr++] = jw;
    double lam[3] = {0.0, 0.0, 0.0};
    if (nr > 0) {
      double AJt[3][kN];
      for (int a = 0; a < nr; ++a) A.apply(rows[a], AJt[a]);
      double K[3][3], rhs[3];
      for (int a = 0; a < nr; ++a) {
        for (int c = 0; c < nr; ++c) K[a][c] = dt * dot(rows[a], AJt[c]);
        rhs[a] = -dot(rows[a], ufree);
      }
      if (!solve_small(nr, K, rhs, lam)) lam[0] = lam[1] = lam[2] = 0.0;
      for (int k = 0; k < kN; ++k) u[k] = ufree[k];
      for (int a = 0; a < nr; ++a)
        for (int k = 0; k < kN; ++k) u[k] += dt * lam[a] * AJt[a][k];
    } else {
      for (int k = 0; k < kN; ++k) u[k] = ufree[k];
    }
    if (any_stuck) {
      int a = 0;
      const double lat = lam[nr - 1];  // nr >= 1 here: the lateral row is last
      for (int i = 0; i < 2; ++i)
        if (stuck[i]) f[i][0] = lam[a++];
      if (stuck[0] && stuck[1]) {
        // Rigid contacts determine only the sum of the lateral forces. Split it in proportion
        // to each wheel's remaining lateral capacity sqrt((mu_s N)^2 - F^2): if any split keeps
        // both wheels inside their friction cones, this one does (then neither breaks loose).
        double cap[2];
        for (int i = 0; i < 2; ++i) {
          const double lim = mu_s * N[i];
          const double c2 = lim * lim - f[i][0] * f[i][0];
          cap[i] = c2 > 0.0 ? sqrt(c2) : 0.0;
        }
        const double cs = cap[0] + cap[1];
        double share0;
        if (cs > 0.0) share0 = cap[0] / cs;
        else share0 = (N[0] + N[1]) > 0.0 ? N[0] / (N[0] + N[1]) : 0.5;
        f[0][1] = share0 * lat;
        f[1][1] = (1.0 - share0) * lat;
      } else {
        f[stuck[0] ? 0 : 1][1] = lat;
      }
    }

    // Stuck wheel that needs more than mu_s N: release the worst one, with kinetic friction
    // in the direction of the force it needed.
    int worst = -1;
    double worst_ratio = 1.0;
    for (int i = 0; i < 2; ++i) {
      if (!stuck[i]) continue;
      const double fm = sqrt(f[i][0] * f[i][0] + f[i][1] * f[i][1]);
      const double lim = mu_s * N[i];
      const double ratio = lim > 0.0 ? fm / lim : (fm > 0.0 ? 2.0 : 0.0);
      if (ratio > worst_ratio * (1.0 + 1e-12)) { worst = i; worst_ratio = ratio; }
    }
    if (worst >= 0) {
      // The worst wheel breaks loose first; a wheel within rounding of it (a symmetric load)
      // breaks loose in the same instant.
      for (int i = 0; i < 2; ++i) {
        if (!stuck[i]) continue;
        const double fm = sqrt(f[i][0] * f[i][0] + f[i][1] * f[i][1]);
        const double lim = mu_s * N[i];
        const double ratio = lim > 0.0 ? fm / lim : (fm > 0.0 ? 2.0 : 0.0);
        if (i != worst && !(ratio > 1.0 && ratio >= worst_ratio * (1.0 - 1e-9))) continue;
        if (fm > 0.0) { slip_dir_[i][0] = f[i][0] / fm; slip_dir_[i][1] = f[i][1] / fm; }
        stuck[i] = false;
        released[i] = true;
      }
      continue;
    }
    // Slipping wheel whose slip velocity reversed within the step: it sticks again.
    bool restuck = false;
    for (int i = 0; i < 2; ++i) {
      if (stuck[i] || released[i]) continue;
      const double s1l = dot(jl[i], u), s1w = u[kW];
      if (s1l * s0[i][0] + s1w * s0[i][1] <= 0.0) { stuck[i] = true; restuck = true; }
    }
    if (!restuck) break;
  }

  // ---- 4. positions and bookkeeping ------------------------------------------------------
  const double c = cos(s_.phi_rad), sn = sin(s_.phi_rad);
  s_.x_m += dt * (u[kV] * c - u[kW] * sn);
  s_.y_m += dt * (u[kV] * sn + u[kW] * c);
  s_.phi_rad += dt * u[kOm];
  s_.theta_r_rad += dt * u[kTr];
  s_.theta_l_rad += dt * u[kTl];
  s_.v_m_s = u[kV];
  s_.w_m_s = u[kW];
  s_.omega_rad_s = u[kOm];
  s_.dtheta_r_rad_s = u[kTr];
  s_.dtheta_l_rad_s = u[kTl];
  s_.t_s += dt;
  stuck_[0] = stuck[0];
  stuck_[1] = stuck[1];
  s_.slipping_r = !stuck[0];
  s_.slipping_l = !stuck[1];
  s_.tau_r_nm = tau_r;
  s_.tau_l_nm = tau_l;
  s_.N_r = N[0];
  s_.N_l = N[1];
  s_.N_c = Nc;
  s_.F_r_n = f[0][0];
  s_.F_l_n = f[1][0];
  s_.L_r_n = f[0][1];
  s_.L_l_n = f[1][1];
  lat_force_prev_n_ = f[0][1] + f[1][1];
  ax_prev_m_s2_ = (f[0][0] + f[1][0] + Fcx + Fsx) / m;
  spin_acc_prev_rad_s2_ = (u[kTr] - u0[kTr] + u[kTl] - u0[kTl]) / dt;
}

}  // namespace slip
#endif  // !__AVR__
