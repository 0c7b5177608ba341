// The independent truth simulator — the one deliberate second implementation of the robot's
// physics (see truth.h for why and how it differs from lib/slipmodel). Host only.
#include "truth.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <vector>

#include <control/cascade.h>
#include <control/cascade_q.h>
#include <control/reference.h>
#include <slipmodel/params.h>  // parameter structs and the table's defaults and ranges

namespace {

const double kPi = 3.14159265358979323846;

struct KeyDef {
  const char* name;
  double def;
  double lo, hi;  // accepted range (inclusive)
};

// Every setting. robot.* / motor.*: the TRUE robot; ctl.*: what the firmware's controller is
// configured with (the nominal values written to meta.json). Effect keys use run-format.md's
// names; the out-of-vocabulary ones are eccentric_wheel, battery_sag and friction_patch.
// The defaults and accepted ranges of the robot and the datasheet motor are the project's one
// parameter table (params/params.json, through the generated slipmodel/params_table.h), not
// copies: the truth and the nominal model start from the same numbers and accept the same
// values. Only the parameters are shared; the physics below is this file's own.
#define TRUTH_ROBOT_KEY(name, def, lo, hi, unit, rf) {"robot." #name, def, lo, hi},
#define TRUTH_MOTOR_KEY(name, def, lo, hi, unit, rf) {"motor." #name, def, lo, hi},
#define TRUTH_CTL_KEY(name, def, lo, hi, unit, rf) {"ctl." #name, def, lo, hi},
const KeyDef kKeys[] = {
    SLIP_ROBOT_PARAMS(TRUTH_ROBOT_KEY) SLIP_MOTOR_PARAMS(TRUTH_MOTOR_KEY)
    SLIP_ROBOT_PARAMS(TRUTH_CTL_KEY) SLIP_MOTOR_PARAMS(TRUTH_CTL_KEY)
    {"ctl.clamp", 1, 0, 1},                {"ctl.fixed", 1, 0, 1},
    // 0 line, 1 arc, 2 figure eight (lib/control's reference for the cascade); 3 segments: the
    // truth's own speed profile, given by tr_set_segments
    {"ref.kind", 0, 0, 3},                 {"ref.accel", 0.5, 1e-3, 20},
    {"ref.cruise", 0.5, 0, 4},             {"ref.radius", 1.0, -100, 100},
    {"ref.alpha", 2.0, 1e-3, 100},         // segments: yaw-rate ramp, rad/s^2
    {"sim.duration", 2.0, 0.01, 3600},     {"sim.dt", 2e-4, 1e-5, 1e-3},
    {"sim.inner_period", 0.025, 1e-3, 1},  {"sim.tel_period", 0.02, 1e-3, 1},
    {"sim.tel_phase", 0.002, 0, 1},        {"sim.cam_period", 1.0 / 30.0, 1e-3, 10},
    {"sim.cam_phase", 0.01, 0, 10},
    {"sim.open_loop", 0, 0, 1},              // 1: constant duties sim.u_r, sim.u_l (no controller)
    {"sim.u_r", 0, -1, 1},                   {"sim.u_l", 0, -1, 1},
    // ---- the recorder (what the robot's board runs and logs); the defaults are this project's
    // firmware pipeline
    {"rec.controller", 0, 0, 1},             // 0: lib/control's cascade; 1: the truth's own PI loop
    {"rec.odometry", 0, 0, 2},               // 0: lib/control's (at ticks); 1: own, at ticks; 2: own, at frames
    {"rec.midpoint", 0, 0, 1},               // own odometry: 0 exact arc, 1 midpoint rule
    {"rec.tel_jitter", 0.0, 0, 0.5},         // telemetry frame time jitter, uniform +-, s
    {"rec.seed", 0, 0, 4294967295.0},        // seed of the jitter
    {"rec.pwm_in_force", 0, 0, 1},           // pwm_*: 0 the duty commanded at the tick; 1 the duty in force (after actuation_delay)
    {"rec.pwm_delay", -1, -1, 1},            // delay of the duty in force reported, s (-1: actuation_delay.delay_s; an external plant's own delay)
    {"pi.kp", 0.04, 0, 10},                  // N m per rad/s
    {"pi.ki", 0.3, 0, 100},                  // N m per rad
    {"pi.j_ff", 0.0023, 0, 1},               // acceleration feed-forward, kg m^2 (per wheel)
    {"pi.tau_limit", slip::table::stall_nm, 1e-3, 100},  // N m
    {"motor_back_emf.ke_ratio", 1.0, 0.1, 10},
    {"driver_voltage_drop.volts", 0.0, 0, 50},
    {"actuation_delay.delay_s", 0.0, 0, 1},
    {"motor_lag.tau_s", 0.0, 0, 10},
    {"axle_viscous.c", 0.0, 0, 1},
    {"axle_coulomb.torque", 0.0, 0, 1},
    {"caster_drag.mu", 0.0, 0, 2},
    {"load_transfer.h", -1.0, -1, 1},        // the robot's centre-of-mass height, m (< 0: robot.h)
    {"sim.spin_share", 1.0, 0, 1},           // share of I_wy whose spin-up reacts on the body
    {"stribeck.mu_k0", -1.0, -1, 10},        // < 0: off
    {"stribeck.v_s", 0.01, 1e-5, 10},
    {"deadband.volts", 0.0, 0, 50},
    {"motor_gain_asymmetry.ratio", 1.0, 0.1, 10},
    {"floor_slope.rad", 0.0, -0.5, 0.5},
    {"payload.mass_kg", 0.0, 0, 50},         // extra mass at c: m_r + mass_kg, I_rz unchanged
    {"eccentric_wheel.eps", 0.0, 0, 0.3},    // r(theta) = r (1 + eps cos(theta + phase))
    {"eccentric_wheel.phase_r", 0.0, -10, 10},
    {"eccentric_wheel.phase_l", 1.3, -10, 10},
    {"battery_sag.r_int", 0.0, 0, 100},      // ohm, shared by both motors
    {"battery_sag.v_per_as", 0.0, 0, 100},   // volts lost per ampere-second drawn
    {"friction_patch.x0", 0.0, -100, 100},   // world x range where mu is scaled
    {"friction_patch.x1", 0.0, -100, 100},
    {"friction_patch.factor", 1.0, 0.01, 10},
};
#undef TRUTH_ROBOT_KEY
#undef TRUTH_MOTOR_KEY
#undef TRUTH_CTL_KEY
const int kKeyCount = static_cast<int>(sizeof(kKeys) / sizeof(kKeys[0]));

const char* const kTelCols[] = {
    "t_s", "enc_r", "enc_l", "omega_r", "omega_l", "tau_cmd_r", "tau_cmd_l", "pwm_r", "pwm_l",
    "x_odo_m", "y_odo_m", "phi_odo_rad",
    // hidden truth (never written to telemetry.csv)
    "true_x_m", "true_y_m", "true_phi_rad", "true_dtheta_r", "true_dtheta_l", "true_slip_r",
    "true_slip_l", "true_tau_r_nm", "true_tau_l_nm", "true_N_r", "true_N_l", "true_N_c",
    "true_v_batt", "clamped", "true_i_r_a", "true_i_l_a"};
const int kTelColCount = static_cast<int>(sizeof(kTelCols) / sizeof(kTelCols[0]));
// what an external plant (tr_set_plant) reports after each step
const char* const kPlantState[] = {"x_m", "y_m", "phi_rad", "theta_r", "theta_l", "dtheta_r", "dtheta_l",
                                   "slip_r", "slip_l", "tau_r_nm", "tau_l_nm", "N_r", "N_l", "N_c",
                                   "v_batt", "i_r_a", "i_l_a"};
const int kPlantStateCount = static_cast<int>(sizeof(kPlantState) / sizeof(kPlantState[0]));
typedef int (*PlantStepFn)(void* user, double t_s, double dt_s, double duty_r, double duty_l, double* state);

const char* const kCamCols[] = {"t_s", "x_m", "y_m", "phi_rad"};
const int kCamColCount = 4;

struct Handle {
  double v[sizeof(kKeys) / sizeof(kKeys[0])];
  char err[256];
  std::vector<double> seg_dur, seg_v, seg_w;  // ref.kind 3: segment durations, targets v, omega
  PlantStepFn plant = nullptr;                // external plant (tr_set_plant) or this file's physics
  void* plant_user = nullptr;
  Handle() {
    for (int i = 0; i < kKeyCount; ++i) v[i] = kKeys[i].def;
    err[0] = '\0';
  }
  double operator()(const char* k) const {
    for (int i = 0; i < kKeyCount; ++i)
      if (strcmp(kKeys[i].name, k) == 0) return v[i];
    return NAN;  // programming error: every name used below is in kKeys
  }
};

int find_key(const char* k) {
  for (int i = 0; i < kKeyCount; ++i)
    if (strcmp(kKeys[i].name, k) == 0) return i;
  return -1;
}

// ---------------------------------------------------------------- contact (velocity level)
// Generalised velocity q = (Vx, Vy, omega, W_r, W_l): c's world velocity, yaw rate, wheel spins.
const int kN = 5;

struct Contact {
  int dim;              // 1 or 2 rows
  double J[2][kN];      // rows of the Jacobian
  double Kinv[2][2];    // inverse of J M^-1 J^T
  double limit;         // impulse bound (friction disc radius), N s
  double P[2];          // accumulated impulse
};

void prepare(Contact& c, const double* Minv) {
  double K[2][2] = {{0, 0}, {0, 0}};
  for (int a = 0; a < c.dim; ++a)
    for (int b = 0; b < c.dim; ++b)
      for (int k = 0; k < kN; ++k) K[a][b] += c.J[a][k] * c.J[b][k] * Minv[k];
  if (c.dim == 1) {
    c.Kinv[0][0] = 1.0 / K[0][0];
  } else {
    const double det = K[0][0] * K[1][1] - K[0][1] * K[1][0];
    c.Kinv[0][0] = K[1][1] / det;
    c.Kinv[1][1] = K[0][0] / det;
    c.Kinv[0][1] = -K[0][1] / det;
    c.Kinv[1][0] = -K[1][0] / det;
  }
  c.P[0] = c.P[1] = 0.0;
}

void rel_vel(const Contact& c, const double* q, double* s) {
  for (int a = 0; a < c.dim; ++a) {
    s[a] = 0.0;
    for (int k = 0; k < kN; ++k) s[a] += c.J[a][k] * q[k];
  }
}

// Projected Gauss-Seidel: each contact in turn takes the impulse that stops its relative
// velocity, projected onto its friction disc. Returns the last sweep's largest impulse change.
double pgs(Contact* cs, int n, double* q, const double* Minv, int max_iter) {
  double last = 0.0;
  for (int it = 0; it < max_iter; ++it) {
    last = 0.0;
    for (int i = 0; i < n; ++i) {
      Contact& c = cs[i];
      double s[2];
      rel_vel(c, q, s);
      double Pn[2] = {c.P[0], c.P[1]};
      for (int a = 0; a < c.dim; ++a)
        for (int b = 0; b < c.dim; ++b) Pn[a] -= c.Kinv[a][b] * s[b];
      const double mag = c.dim == 1 ? fabs(Pn[0]) : hypot(Pn[0], Pn[1]);
      if (mag > c.limit) {
        // Coulomb: a sliding contact's impulse opposes its relative velocity (not the
        // K-metric projection of the stopping impulse, which would tilt the force sideways
        // wherever the contact's effective mass couples the directions).
        const double sm = c.dim == 1 ? fabs(s[0]) : hypot(s[0], s[1]);
        if (sm > 1e-12) {
          Pn[0] = -c.limit * s[0] / sm;
          Pn[1] = c.dim == 2 ? -c.limit * s[1] / sm : 0.0;
        } else {
          const double f = c.limit / mag;
          Pn[0] *= f;
          Pn[1] *= f;
        }
      }
      const double d0 = Pn[0] - c.P[0], d1 = c.dim == 2 ? Pn[1] - c.P[1] : 0.0;
      for (int k = 0; k < kN; ++k) q[k] += Minv[k] * (c.J[0][k] * d0 + (c.dim == 2 ? c.J[1][k] * d1 : 0.0));
      c.P[0] = Pn[0];
      if (c.dim == 2) c.P[1] = Pn[1];
      last = fmax(last, fmax(fabs(d0), fabs(d1)));
    }
    if (last < 1e-13) break;
  }
  return last;
}

uint32_t to_b32(double rad) {
  const double turns = rad / (2.0 * kPi);
  return static_cast<uint32_t>(static_cast<int64_t>(llround((turns - floor(turns)) * 4294967296.0)));
}

int32_t counts(double theta) { return static_cast<int32_t>(floor(theta * slip::kEncoderPpr / (2.0 * kPi))); }

struct CtlIO {  // what the board reports after an inner step
  double omega_r = 0, omega_l = 0, tau_r = 0, tau_l = 0, pwm_r = 0, pwm_l = 0;
  double x = 0, y = 0, phi = 0;
  int clamped = 0;
};


// ------------------------------------------------------------------ the recorder's own code
// Everything below up to tr_new is the truth simulator's own recorder: a reference speed
// profile, odometry and a PI wheel-speed loop that are NOT lib/control's, so that recordings
// can come from a board that is not this project's firmware.

uint64_t splitmix64(uint64_t& s) {
  uint64_t z = (s += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
double uniform01(uint64_t& s) { return (splitmix64(s) >> 11) * (1.0 / 9007199254740992.0); }

// A speed step toward a target at a bounded rate: value at time tau after the step's start.
void ramp(double from, double to, double rate, double tau, double* val, double* der) {
  const double dist = fabs(to - from), t_end = dist / rate;
  if (tau >= t_end) {
    *val = to;
    *der = 0.0;
  } else {
    const double sg = to > from ? 1.0 : -1.0;
    *val = from + sg * rate * tau;
    *der = sg * rate;
  }
}

// The truth's own reference speeds (v, omega and their derivatives) for every kind:
//  * line/arc/figure eight: the same definitions as lib/control's reference.h (accelerate at
//    accel to cruise; curvature 0, 1/R, cos(2 pi s/L)/R with L = 2 pi beta |R|), computed here
//    in double precision (used by the PI loop, whose reference is wheel speeds);
//  * segments: from rest, segment i (start T_i, duration D_i) ramps v toward v_i at +-accel
//    and omega toward omega_i at +-alpha, then holds; after the last segment its targets hold.
//    The reference pose is the integral of (v, omega) from the origin facing +x.
struct SpeedRef {
  int kind = 0;
  double accel = 0.5, cruise = 0.5, radius = 1.0, alpha = 2.0;
  std::vector<double> T, D, V, W, v0, w0;  // segment starts, durations, targets, start values

  void init(const Handle& H) {
    kind = static_cast<int>(lround(H("ref.kind")));
    accel = H("ref.accel"); cruise = H("ref.cruise"); radius = H("ref.radius"); alpha = H("ref.alpha");
    D = H.seg_dur; V = H.seg_v; W = H.seg_w;
    T.assign(D.size(), 0.0); v0.assign(D.size(), 0.0); w0.assign(D.size(), 0.0);
    double t = 0.0, v = 0.0, w = 0.0, dv, dw;
    for (size_t i = 0; i < D.size(); ++i) {
      T[i] = t; v0[i] = v; w0[i] = w;
      ramp(v, V[i], accel, D[i], &v, &dv);
      ramp(w, W[i], alpha, D[i], &w, &dw);
      t += D[i];
    }
  }
  // v, omega, dv/dt, domega/dt at time t >= 0
  void at(double t, double* v, double* w, double* dv, double* dw) const {
    if (t < 0) t = 0;
    if (kind == 3) {
      size_t i = 0;
      while (i + 1 < D.size() && t >= T[i + 1]) ++i;
      ramp(v0[i], V[i], accel, t - T[i], v, dv);
      ramp(w0[i], W[i], alpha, t - T[i], w, dw);
      return;
    }
    const double t_r = cruise / accel;
    double s;
    if (t < t_r) { *v = accel * t; *dv = accel; s = 0.5 * accel * t * t; }
    else { *v = cruise; *dv = 0.0; s = 0.5 * cruise * t_r + cruise * (t - t_r); }
    double kappa = 0.0, dkappa = 0.0;
    if (kind == 1) {
      kappa = 1.0 / radius;
    } else if (kind == 2) {
      const double L = 2.0 * kPi * ctl::kEightBeta * fabs(radius), a = 2.0 * kPi * s / L;
      kappa = cos(a) / radius;
      dkappa = -sin(a) * (2.0 * kPi / L) / radius;
    }
    *w = *v * kappa;
    *dw = *dv * kappa + *v * *v * dkappa;
  }
};

// Recorder odometry from the encoder counts with the nominal r and b (double precision):
// distance steps d_r, d_l, ds = (d_r + d_l)/2, dphi = (d_r - d_l)/(2b); the exact arc
// (x += ds/dphi (sin(phi + dphi) - sin phi), ...) or the midpoint rule (heading phi + dphi/2).
struct OwnOdometry {
  double r = 0, b = 0;  // the controller's nominal r and b (ctl.r, ctl.b)
  bool midpoint = false;
  int32_t er = 0, el = 0;
  double x = 0, y = 0, phi = 0;
  void update(int32_t enc_r, int32_t enc_l) {
    const double k = 2.0 * kPi / slip::kEncoderPpr * r;
    const double dr = (enc_r - er) * k, dl = (enc_l - el) * k;
    er = enc_r; el = enc_l;
    const double ds = 0.5 * (dr + dl), dphi = (dr - dl) / (2.0 * b);
    if (midpoint || fabs(dphi) < 1e-9) {
      x += ds * cos(phi + 0.5 * dphi);
      y += ds * sin(phi + 0.5 * dphi);
    } else {
      const double R = ds / dphi;
      x += R * (sin(phi + dphi) - sin(phi));
      y -= R * (cos(phi + dphi) - cos(phi));
    }
    phi += dphi;
  }
};

// A PI wheel-speed loop per wheel (not lib/control's cascade): wheel-speed references
// (v +- b omega)/r from the reference, speed estimate = count difference over the inner period,
// torque = j_ff dw_ref + kp e + ki integral(e) limited to +-tau_limit (the integral stops while
// the torque is limited and the error would drive it further), duty from the datasheet motor:
// u = tau/stall + w/no_load, limited to [-1, 1].
struct PiLoop {
  // set from pi.* and the controller's nominal ctl.* before use
  double kp = 0, ki = 0, j_ff = 0, tau_lim = 0, r = 0, b = 0;
  double stall = 0, no_load = 0, period = 0;
  int32_t last[2] = {0, 0};
  bool first = true;
  double integ[2] = {0, 0}, omega[2] = {0, 0}, tau[2] = {0, 0}, duty[2] = {0, 0};
  int limited = 0;
  void step(int32_t enc_r, int32_t enc_l, double v, double w, double dv, double dw) {
    const int32_t enc[2] = {enc_r, enc_l};
    const double ref[2] = {(v + b * w) / r, (v - b * w) / r};
    const double dref[2] = {(dv + b * dw) / r, (dv - b * dw) / r};
    limited = 0;
    for (int i = 0; i < 2; ++i) {
      omega[i] = first ? 0.0 : (enc[i] - last[i]) * (2.0 * kPi / slip::kEncoderPpr) / period;
      last[i] = enc[i];
      const double e = ref[i] - omega[i];
      const double trial_i = integ[i] + e * period;
      double t = j_ff * dref[i] + kp * e + ki * trial_i;
      if (fabs(t) > tau_lim) {
        limited |= 1 << i;
        // anti-windup: keep the integral unless the error pulls the torque back inside
        if (!((t > 0) == (e > 0))) integ[i] = trial_i;
        t = t > 0 ? tau_lim : -tau_lim;
      } else {
        integ[i] = trial_i;
      }
      tau[i] = t;
      duty[i] = fmax(-1.0, fmin(1.0, t / stall + omega[i] / no_load));
    }
    first = false;
  }
};
}  // namespace

extern "C" {

void* tr_new(void) { return new Handle(); }
void tr_free(void* h) { delete static_cast<Handle*>(h); }
const char* tr_last_error(void* h) { return h ? static_cast<Handle*>(h)->err : "null handle"; }
int tr_key_count(void) { return kKeyCount; }
const char* tr_key_name(int i) { return (i >= 0 && i < kKeyCount) ? kKeys[i].name : nullptr; }
int tr_tel_cols(void) { return kTelColCount; }
const char* tr_tel_col_name(int i) { return (i >= 0 && i < kTelColCount) ? kTelCols[i] : nullptr; }
int tr_cam_cols(void) { return kCamColCount; }
const char* tr_cam_col_name(int i) { return (i >= 0 && i < kCamColCount) ? kCamCols[i] : nullptr; }

int tr_set(void* p, const char* key, double value) {
  if (!p || !key) return -3;
  Handle* h = static_cast<Handle*>(p);
  const int i = find_key(key);
  if (i < 0) {
    snprintf(h->err, sizeof h->err, "unknown key '%s'", key);
    return -1;
  }
  if (!isfinite(value) || value < kKeys[i].lo || value > kKeys[i].hi) {
    snprintf(h->err, sizeof h->err, "%s = %g is outside [%g, %g]", key, value, kKeys[i].lo, kKeys[i].hi);
    return -2;
  }
  h->v[i] = value;
  return 0;
}

int tr_set_plant(void* p, void* fn, void* user) {
  if (!p) return -3;
  Handle* h = static_cast<Handle*>(p);
  h->plant = reinterpret_cast<PlantStepFn>(fn);
  h->plant_user = user;
  return 0;
}
int tr_plant_state_count(void) { return kPlantStateCount; }
const char* tr_plant_state_name(int i) { return (i >= 0 && i < kPlantStateCount) ? kPlantState[i] : nullptr; }

int tr_set_segments(void* p, int n, const double* dur, const double* v, const double* w) {
  if (!p || n < 0 || (n > 0 && (!dur || !v || !w))) return -3;
  Handle* h = static_cast<Handle*>(p);
  for (int i = 0; i < n; ++i) {
    if (!isfinite(dur[i]) || dur[i] <= 0 || !isfinite(v[i]) || fabs(v[i]) > 4 || !isfinite(w[i]) || fabs(w[i]) > 16) {
      snprintf(h->err, sizeof h->err, "segment %d: duration > 0, |v| <= 4 m/s, |omega| <= 16 rad/s", i);
      return -2;
    }
  }
  h->seg_dur.assign(dur, dur + n);
  h->seg_v.assign(v, v + n);
  h->seg_w.assign(w, w + n);
  return 0;
}

int tr_get(void* p, const char* key, double* out) {
  if (!p || !key || !out) return -3;
  Handle* h = static_cast<Handle*>(p);
  const int i = find_key(key);
  if (i < 0) {
    snprintf(h->err, sizeof h->err, "unknown key '%s'", key);
    return -1;
  }
  *out = h->v[i];
  return 0;
}

int tr_run(void* p, int max_tel, double* tel, int* n_tel, int max_cam, double* cam, int* n_cam) {
  if (!p || !tel || !n_tel || !cam || !n_cam || max_tel < 1 || max_cam < 1) return -3;
  Handle& H = *static_cast<Handle*>(p);
  // ---- true parameters
  const double mu_s = H("robot.mu_s"), mu_k = fmin(H("robot.mu_k"), mu_s);
  // Mass layout: the platform (m_r, with a payload at its centre of mass) has its centre of
  // mass d ahead of the axle centre o and its yaw inertia I_rz about it; each wheel (m_w, I_wz
  // about the vertical) sits on the axle, b to the side. The robot's centre of mass c is then
  // d_c = m_p d / m ahead of o; the caster contact stays d + e ahead of o, e_c = d + e - d_c
  // ahead of c; the yaw inertia about c is that of the masses where they sit.
  const double b = H("robot.b"), e0 = H("robot.e"), d0 = H("robot.d"), g = H("robot.g");
  const double m_p = H("robot.m_r") + H("payload.mass_kg"), m_w = H("robot.m_w");
  const double m = m_p + 2.0 * m_w;
  const double d = m_p * d0 / m, e = d0 + e0 - d;
  const double Ic = H("robot.I_rz") + m_p * (d0 - d) * (d0 - d) +
                    2.0 * (H("robot.I_wz") + m_w * (b * b + d * d));
  // the centre of mass's height: robot.h, or load_transfer.h where set; both balances use it
  const double h_com = H("load_transfer.h") >= 0.0 ? H("load_transfer.h") : H("robot.h");
  const double spin_share = H("sim.spin_share");
  const double Iw = H("robot.I_wy"), r0 = H("robot.r");
  const double V0 = H("motor.supply_v"), w0 = H("motor.no_load_rad_s"), stall = H("motor.stall_nm");
  const double k_t = V0 / w0;  // SI motor constant (torque per ampere = volts per rad/s)
  const double stall_a = H("motor.stall_a");
  const double ke_ratio = H("motor_back_emf.ke_ratio"), v_drop = H("driver_voltage_drop.volts");
  const double delay = H("actuation_delay.delay_s"), lag = H("motor_lag.tau_s");
  const double c_visc = H("axle_viscous.c"), T_coul = H("axle_coulomb.torque");
  const double mu_caster = H("caster_drag.mu");
  const double mu_k0 = H("stribeck.mu_k0"), v_s = H("stribeck.v_s");
  const double v_dead = H("deadband.volts"), asym = H("motor_gain_asymmetry.ratio");
  const double slope = H("floor_slope.rad");
  const double ecc = H("eccentric_wheel.eps"), ph_r = H("eccentric_wheel.phase_r"), ph_l = H("eccentric_wheel.phase_l");
  const double r_int = H("battery_sag.r_int"), v_per_as = H("battery_sag.v_per_as");
  const double px0 = H("friction_patch.x0"), px1 = H("friction_patch.x1"), pfac = H("friction_patch.factor");
  // ---- timing (all events on the step grid)
  const double dt = H("sim.dt");
  const long n_steps = lround(H("sim.duration") / dt);
  const long inner_n = lround(H("sim.inner_period") / dt), tel_n = lround(H("sim.tel_period") / dt);
  const long tel_0 = lround(H("sim.tel_phase") / dt);
  if (inner_n < 1 || tel_n < 1 || fabs(inner_n * dt - H("sim.inner_period")) > 1e-9 ||
      fabs(tel_n * dt - H("sim.tel_period")) > 1e-9) {
    snprintf(H.err, sizeof H.err, "sim.dt must divide the inner and telemetry periods");
    return -2;
  }
  // ---- the firmware's controller, configured with the nominal (ctl.*) values
  slip::RobotParams cr;
  cr.mu_s = H("ctl.mu_s"); cr.mu_k = H("ctl.mu_k"); cr.b = H("ctl.b"); cr.e = H("ctl.e");
  cr.d = H("ctl.d"); cr.g = H("ctl.g"); cr.h = H("ctl.h"); cr.m_r = H("ctl.m_r");
  cr.I_rz = H("ctl.I_rz"); cr.I_wz = H("ctl.I_wz"); cr.I_wy = H("ctl.I_wy"); cr.r = H("ctl.r");
  cr.m_w = H("ctl.m_w");
  slip::MotorParams cm;
  cm.supply_v = H("ctl.supply_v"); cm.no_load_rad_s = H("ctl.no_load_rad_s"); cm.stall_nm = H("ctl.stall_nm");
  cm.stall_a = H("ctl.stall_a");
  const bool fixed = H("ctl.fixed") != 0.0;
  const ctl::ControlConfig cfg = ctl::make_control_config(cr, cm, ctl::default_gains(), H("ctl.clamp") != 0.0);
  const uint32_t inner_us = static_cast<uint32_t>(llround(inner_n * dt * 1e6));
  const ctl::ControlConfigQ cfg_q(cfg, inner_us);
  if (fixed && !cfg_q.ok) {
    snprintf(H.err, sizeof H.err, "controller configuration does not fit the fixed-point formats");
    return -2;
  }
  const int ref_kind = static_cast<int>(lround(H("ref.kind")));
  const bool segments = ref_kind == 3;
  if (segments && H.seg_dur.empty()) {
    snprintf(H.err, sizeof H.err, "ref.kind 3 (segments) needs a segment list (tr_set_segments)");
    return -2;
  }
  SpeedRef sref;
  sref.init(H);
  const ctl::ReferenceSpec ref{static_cast<ctl::PathKind>(segments ? 0 : ref_kind), static_cast<float>(H("ref.accel")),
                               static_cast<float>(H("ref.cruise")), static_cast<float>(H("ref.radius"))};
  if (!ref.valid()) {
    snprintf(H.err, sizeof H.err, "invalid reference (accel in (0,20], cruise in [0,4], |R| in [0.05,100])");
    return -2;
  }
  const ctl::ReferenceSpecQ ref_q(ref);
  ctl::Controller fc(cfg);
  ctl::ControllerQ qc(cfg_q);
  fc.reset(0, 0, ctl::Pose{0.0f, 0.0f, 0.0f});
  qc.reset(0, 0, ctl::PoseQ{0, 0, 0});
  // ---- the recorder
  const bool pi_mode = H("rec.controller") != 0.0;
  const int odo_mode = static_cast<int>(lround(H("rec.odometry")));
  if (pi_mode && odo_mode == 0) {
    snprintf(H.err, sizeof H.err, "the PI recorder has no lib/control odometry: rec.odometry must be 1 or 2");
    return -2;
  }
  OwnOdometry own_odo;
  own_odo.r = cr.r; own_odo.b = cr.b; own_odo.midpoint = H("rec.midpoint") != 0.0;
  PiLoop pi;
  pi.kp = H("pi.kp"); pi.ki = H("pi.ki"); pi.j_ff = H("pi.j_ff"); pi.tau_lim = H("pi.tau_limit");
  pi.r = cr.r; pi.b = cr.b; pi.stall = cm.stall_nm; pi.no_load = cm.no_load_rad_s; pi.period = inner_n * dt;
  // reference pose of a segment profile (the cascade's outer loop needs it): the integral of
  // (v, omega), advanced every simulation step with the trapezoid rule on omega and the
  // midpoint heading for the position (v and omega are piecewise linear in time)
  double ref_x = 0.0, ref_y = 0.0, ref_phi = 0.0, ref_v = 0.0, ref_w = 0.0, ref_dv = 0.0, ref_dw = 0.0;
  sref.at(0.0, &ref_v, &ref_w, &ref_dv, &ref_dw);
  const double jitter = H("rec.tel_jitter");
  uint64_t rng = static_cast<uint64_t>(H("rec.seed"));
  auto next_frame = [&](long j) -> long {  // step of telemetry frame j (jittered, on the grid)
    long n = tel_0 + j * tel_n;
    if (jitter > 0.0) n += lround((2.0 * uniform01(rng) - 1.0) * jitter / dt);
    return n;
  };

  // ---- state: c in world coordinates; the robot starts at rest with o at the origin, facing +x
  double X = d, Y = 0.0, phi = 0.0;
  double q[kN] = {0, 0, 0, 0, 0};
  double th_r = 0.0, th_l = 0.0;
  const double Minv[kN] = {1.0 / m, 1.0 / m, 1.0 / Ic, 1.0 / Iw, 1.0 / Iw};
  bool stuck_r = true, stuck_l = true;
  double tau_del_r = 0.0, tau_del_l = 0.0;  // delivered torques (after the lag)
  double lat_prev = 0.0, ax_prev = 0.0;     // body-frame lateral friction force, forward accel of c
  double spin_prev = 0.0;                   // the wheels' summed spin acceleration, rad/s^2
  double charge_as = 0.0, v_batt = V0, N_r = 0, N_l = 0, N_c = 0;
  // command history for the actuation delay (commands change only at ticks): a ring of the
  // last kHist ticks (>= 4.096 s at the shortest inner period, 1 ms; the delay is <= 1 s)
  const int kHist = 4096;
  std::vector<double> hist_t(kHist), hist_r(kHist), hist_l(kHist);
  long hist_n = 0;
  CtlIO io;
  double phi_odo_unwrapped = 0.0;
  uint32_t phi_odo_last = 0;
  int nt = 0, nc = 0;
  long next_cam_j = 0;
  const double cam_T = H("sim.cam_period"), cam_0 = H("sim.cam_phase");
  double last_tau_r = 0, last_tau_l = 0;
  double cur_r = 0.0, cur_l = 0.0;  // armature currents (after the lag), A
  long tel_j = 0, tel_next = next_frame(0), tel_prev = -1;
  const PlantStepFn ext = H.plant;
  double ext_state[kPlantStateCount] = {0};
  double xo_ext = 0.0, yo_ext = 0.0;  // an external plant's axle centre

  for (long n = 0; n <= n_steps; ++n) {
    const double t = n * dt;
    // axle centre and its pose
    const double ct = cos(phi), st = sin(phi);
    // ---- board: inner tick (and outer every other tick), then telemetry
    if (n % inner_n == 0) {
      const long k = n / inner_n;
      const int32_t er = counts(th_r), el = counts(th_l);
      uint32_t phi_b32 = 0;
      ctl::RefSample rs{};
      ctl::RefSampleQ rq{};
      if (segments && k % 2 == 0) {  // the truth's own reference in the controller's formats
        rs = ctl::RefSample{static_cast<float>(ref_x), static_cast<float>(ref_y), static_cast<float>(ref_phi),
                            static_cast<float>(ref_v), static_cast<float>(ref_w), static_cast<float>(ref_dv),
                            static_cast<float>(ref_dw)};
        rq.x_q20 = static_cast<int32_t>(llround(ref_x * 1048576.0));
        rq.y_q20 = static_cast<int32_t>(llround(ref_y * 1048576.0));
        rq.phi_b32 = to_b32(ref_phi);
        rq.v_q12 = static_cast<int16_t>(llround(ref_v * 4096.0));
        rq.omega_q11 = static_cast<int16_t>(llround(ref_w * 2048.0));
        rq.dv_q12 = static_cast<int16_t>(llround(ref_dv * 4096.0));
        rq.domega_q11 = static_cast<int16_t>(llround(ref_dw * 2048.0));
      }
      if (pi_mode) {
        double v, w, dv, dw;
        sref.at(t, &v, &w, &dv, &dw);
        pi.step(er, el, v, w, dv, dw);
        io.pwm_r = pi.duty[0]; io.pwm_l = pi.duty[1]; io.tau_r = pi.tau[0]; io.tau_l = pi.tau[1];
        io.clamped = pi.limited;
        io.omega_r = pi.omega[0]; io.omega_l = pi.omega[1];
      } else if (fixed) {
        // tick 0 starts the experiment (reset, outer step at t = 0, first command), as the
        // firmware's start tick does; then inner steps, the outer step after every second one
        const ctl::RefSampleQ r0 = segments ? rq : ctl::reference_at_q(ref_q, 0);
        const ctl::InnerOutQ& o = k == 0 ? qc.start(er, el, ctl::PoseQ{0, 0, 0}, r0)
                                         : qc.inner_step(er, el, static_cast<uint32_t>(llround(inner_n * dt * 1e6)));
        if (k > 0 && k % 2 == 0)
          qc.outer_step(segments ? rq : ctl::reference_at_q(ref_q, static_cast<uint32_t>(llround(k * inner_n * dt * 1000.0))));
        io.pwm_r = o.pwm_r_q15 / 32768.0; io.pwm_l = o.pwm_l_q15 / 32768.0;
        io.tau_r = o.tau_r_q16 / 65536.0; io.tau_l = o.tau_l_q16 / 65536.0;
        io.clamped = (o.clamped_r ? 1 : 0) + (o.clamped_l ? 2 : 0);
        io.omega_r = qc.odometry().omega_r_q8() / 256.0; io.omega_l = qc.odometry().omega_l_q8() / 256.0;
        io.x = qc.odometry().pose().x_q20 / 1048576.0; io.y = qc.odometry().pose().y_q20 / 1048576.0;
        phi_b32 = qc.odometry().pose().phi_b32;
      } else {
        const ctl::InnerOut& o = k == 0 ? fc.start(er, el, ctl::Pose{0.0f, 0.0f, 0.0f}, segments ? rs : ctl::reference_at(ref, 0.0f))
                                        : fc.inner_step(er, el, static_cast<float>(inner_n * dt));
        if (k > 0 && k % 2 == 0) fc.outer_step(segments ? rs : ctl::reference_at(ref, static_cast<float>(k * inner_n * dt)));
        io.pwm_r = o.pwm_r; io.pwm_l = o.pwm_l; io.tau_r = o.tau_r_nm; io.tau_l = o.tau_l_nm;
        io.clamped = (o.clamped_r ? 1 : 0) + (o.clamped_l ? 2 : 0);
        io.omega_r = fc.odometry().omega_r_rad_s(); io.omega_l = fc.odometry().omega_l_rad_s();
        io.x = fc.odometry().pose().x_m; io.y = fc.odometry().pose().y_m;
        phi_b32 = to_b32(fc.odometry().pose().phi_rad);
      }
      if (odo_mode == 0) {
        phi_odo_unwrapped += static_cast<int32_t>(phi_b32 - phi_odo_last) * (2.0 * kPi / 4294967296.0);
        phi_odo_last = phi_b32;
        io.phi = phi_odo_unwrapped;
      } else if (odo_mode == 1) {  // the recorder's own odometry at the ticks
        own_odo.update(er, el);
        io.x = own_odo.x; io.y = own_odo.y; io.phi = own_odo.phi;
      }
      if (H("sim.open_loop") != 0.0) { io.pwm_r = H("sim.u_r"); io.pwm_l = H("sim.u_l"); }
      const long slot = hist_n % kHist;
      hist_t[slot] = t; hist_r[slot] = io.pwm_r; hist_l[slot] = io.pwm_l; ++hist_n;
    }
    const double xo = ext ? xo_ext : X - d * ct, yo = ext ? yo_ext : Y - d * st;
    while (tel_next <= tel_prev || tel_next < 0) tel_next = next_frame(++tel_j);  // frames stay in order
    if (n == tel_next) {
      tel_prev = n;
      tel_next = next_frame(++tel_j);
      if (nt >= max_tel) { snprintf(H.err, sizeof H.err, "telemetry buffer too small"); return -3; }
      if (odo_mode == 2) {  // the recorder's own odometry at the frames
        own_odo.update(counts(th_r), counts(th_l));
        io.x = own_odo.x; io.y = own_odo.y; io.phi = own_odo.phi;
      }
      double rep_r = io.pwm_r, rep_l = io.pwm_l;  // the duty reported
      if (H("rec.pwm_in_force") != 0.0) {        // the duty in force: the delayed command
        rep_r = rep_l = 0.0;
        const double rep_delay = H("rec.pwm_delay") >= 0.0 ? H("rec.pwm_delay") : delay;
        for (long i = hist_n - 1; i >= 0 && i >= hist_n - kHist; --i)
          if (hist_t[i % kHist] <= t - rep_delay + 1e-12) { rep_r = hist_r[i % kHist]; rep_l = hist_l[i % kHist]; break; }
      }
      double* row = tel + static_cast<long>(nt) * kTelColCount;
      const double vals[] = {t, double(counts(th_r)), double(counts(th_l)), io.omega_r, io.omega_l, io.tau_r, io.tau_l,
                             rep_r, rep_l, io.x, io.y, io.phi, xo, yo, phi, q[3], q[4],
                             stuck_r ? 0.0 : 1.0, stuck_l ? 0.0 : 1.0, last_tau_r, last_tau_l, N_r, N_l, N_c,
                             v_batt, double(io.clamped), cur_r, cur_l};
      memcpy(row, vals, sizeof vals);
      ++nt;
    }
    while (lround((cam_0 + next_cam_j * cam_T) / dt) <= n) {
      if (lround((cam_0 + next_cam_j * cam_T) / dt) == n) {
        if (nc >= max_cam) { snprintf(H.err, sizeof H.err, "camera buffer too small"); return -3; }
        double* row = cam + static_cast<long>(nc) * kCamColCount;
        row[0] = t; row[1] = xo; row[2] = yo; row[3] = phi;
        ++nc;
      }
      ++next_cam_j;
    }
    if (n == n_steps) break;

    // ---- drive: delayed duty -> voltage (battery, driver drop, deadband) -> motor -> lag
    double u_r = 0.0, u_l = 0.0;
    for (long i = hist_n - 1; i >= 0 && i >= hist_n - kHist; --i)
      if (hist_t[i % kHist] <= t - delay + 1e-12) { u_r = hist_r[i % kHist]; u_l = hist_l[i % kHist]; break; }
    u_r = fmax(-1.0, fmin(1.0, u_r));
    u_l = fmax(-1.0, fmin(1.0, u_l));
    if (ext) {  // another engine's physics; the recorder above and below is unchanged
      if (ext(H.plant_user, t, dt, u_r, u_l, ext_state) != 0) {
        snprintf(H.err, sizeof H.err, "external plant failed at t = %g s", t);
        return -2;
      }
      const double* s = ext_state;
      xo_ext = s[0]; yo_ext = s[1]; phi = s[2]; th_r = s[3]; th_l = s[4]; q[3] = s[5]; q[4] = s[6];
      stuck_r = s[7] == 0.0; stuck_l = s[8] == 0.0; last_tau_r = s[9]; last_tau_l = s[10];
      N_r = s[11]; N_l = s[12]; N_c = s[13]; v_batt = s[14]; cur_r = s[15]; cur_l = s[16];
      X = xo_ext; Y = yo_ext;  // for the divergence check below
    } else {
    const double i_draw = (fabs(tau_del_r) + fabs(tau_del_l)) / k_t;
    charge_as += i_draw * dt;
    v_batt = V0 - r_int * i_draw - v_per_as * charge_as;
    const double v_avail = fmax(0.0, v_batt - v_drop);
    double tau_cmd[2], i_cmd[2];
    const double uu[2] = {u_r, u_l}, ww[2] = {q[3], q[4]};
    for (int i = 0; i < 2; ++i) {
      double V = uu[i] * v_avail;
      V = (V > 0 ? 1.0 : -1.0) * fmax(fabs(V) - v_dead, 0.0);
      // armature: I = (V - k_e' W)/R, tau = k_t I, with k_t/R = stall/V0 and k_e' = ke_ratio V0/w0
      double tau = stall * (V - ke_ratio * (V0 / w0) * ww[i]) / V0;
      tau = fmax(-stall, fmin(stall, tau));
      tau_cmd[i] = tau;
      // the same armature current in amperes (1/R = stall_a/V0): the electrical side, before the
      // axle's friction; the gain asymmetry below is one of torque per ampere, not of current
      double cur = stall_a * (V - ke_ratio * (V0 / w0) * ww[i]) / V0;
      i_cmd[i] = fmax(-stall_a, fmin(stall_a, cur));
    }
    tau_cmd[0] *= sqrt(asym);
    tau_cmd[1] /= sqrt(asym);
    if (lag > 0.0) {  // the lag is the armature's: current and torque follow it together
      const double a = 1.0 - exp(-dt / lag);
      tau_del_r += a * (tau_cmd[0] - tau_del_r);
      tau_del_l += a * (tau_cmd[1] - tau_del_l);
      cur_r += a * (i_cmd[0] - cur_r);
      cur_l += a * (i_cmd[1] - cur_l);
    } else {
      tau_del_r = tau_cmd[0];
      tau_del_l = tau_cmd[1];
      cur_r = i_cmd[0];
      cur_l = i_cmd[1];
    }
    last_tau_r = tau_del_r;
    last_tau_l = tau_del_l;

    // ---- normal forces: caster from the pitch balance about c, wheels from the roll balance.
    // Pitch moments about c (the body does not pitch; every part translates with c): the
    // wheels' loads d behind c, the caster's e ahead, the ground's forward forces at depth
    // h_com; they change the wheels' spin momentum spin_share Iw (theta'_r + theta'_l), the
    // share of the wheels' spin inertia that turns with them about the axle:
    //   d (N_r + N_l) - e N_c - h_com m a_x = spin_share Iw (theta''_r + theta''_l)
    const double Wn = m * g * cos(slope);
    N_c = fmin(Wn, fmax(0.0, (Wn * d - m * ax_prev * h_com - spin_share * Iw * spin_prev) / (d + e)));
    const double Nw = Wn - N_c;
    const double dN = h_com * lat_prev / b;  // a left lateral force loads the right wheel
    N_r = fmax(0.0, 0.5 * (Nw + dN));
    N_l = fmax(0.0, 0.5 * (Nw - dN));
    if (N_r == 0.0) N_l = Nw;
    if (N_l == 0.0) N_r = Nw;

    // ---- free velocity update: gravity along the slope, motor torque, implicit axle viscous
    const double q_old0 = q[0], q_old1 = q[1], q_old34 = q[3] + q[4];
    q[0] += dt * (-m * g * sin(slope)) / m;
    q[3] = (Iw * q[3] + dt * tau_del_r) / (Iw + dt * c_visc);
    q[4] = (Iw * q[4] + dt * tau_del_l) / (Iw + dt * c_visc);

    // ---- contacts
    const double r_r = r0 * (1.0 + ecc * cos(th_r + ph_r));
    const double r_l = r0 * (1.0 + ecc * cos(th_l + ph_l));
    Contact cs[5];
    int ncs = 0;
    const double nx = -st, ny = ct;  // body y axis (left) in world
    const double rho[2][2] = {{-d * ct + b * st, -d * st - b * ct},   // right contact - c
                              {-d * ct - b * st, -d * st + b * ct}};  // left contact - c
    const double rw[2] = {r_r, r_l};
    const bool stuck[2] = {stuck_r, stuck_l};
    const double Nwheel[2] = {N_r, N_l};
    double s_pre[2];
    for (int i = 0; i < 2; ++i) {
      Contact& c = cs[ncs++];
      c.dim = 2;
      memset(c.J, 0, sizeof c.J);
      c.J[0][0] = 1.0; c.J[0][2] = -rho[i][1]; c.J[0][3 + i] = -rw[i] * ct;
      c.J[1][1] = 1.0; c.J[1][2] = rho[i][0];  c.J[1][3 + i] = -rw[i] * st;
      double s[2];
      rel_vel(c, q, s);
      s_pre[i] = hypot(s[0], s[1]);
      double mu;
      if (stuck[i]) {
        mu = mu_s;
      } else {
        mu = mu_k;
        if (mu_k0 >= 0.0) mu = fmin(mu_s, mu_k + (mu_k0 - mu_k) * exp(-(s_pre[i] / v_s) * (s_pre[i] / v_s)));
      }
      const double xc = X + rho[i][0];
      if (px1 > px0 && xc >= px0 && xc <= px1) mu *= pfac;
      c.limit = mu * Nwheel[i] * dt;
      prepare(c, Minv);
    }
    if (mu_caster > 0.0) {
      Contact& c = cs[ncs++];
      c.dim = 2;
      memset(c.J, 0, sizeof c.J);
      const double rx = e * ct, ry = e * st;
      c.J[0][0] = 1.0; c.J[0][2] = -ry;
      c.J[1][1] = 1.0; c.J[1][2] = rx;
      c.limit = mu_caster * N_c * dt;
      prepare(c, Minv);
    }
    if (T_coul > 0.0) {
      for (int i = 0; i < 2; ++i) {
        Contact& c = cs[ncs++];
        c.dim = 1;
        memset(c.J, 0, sizeof c.J);
        c.J[0][3 + i] = 1.0;
        c.limit = T_coul * dt;
        prepare(c, Minv);
      }
    }
    pgs(cs, ncs, q, Minv, 200);
    for (int i = 0; i < 2; ++i) {
      double s[2];
      rel_vel(cs[i], q, s);
      const bool at_limit = hypot(cs[i].P[0], cs[i].P[1]) >= cs[i].limit * (1.0 - 1e-9);
      const bool st_now = !(at_limit && hypot(s[0], s[1]) > 1e-7);
      if (i == 0) stuck_r = st_now; else stuck_l = st_now;
    }
    // lateral friction force (body frame) of both wheels, for the next step's roll balance
    lat_prev = ((cs[0].P[0] + cs[1].P[0]) * nx + (cs[0].P[1] + cs[1].P[1]) * ny) / dt;
    ax_prev = ((q[0] - q_old0) * ct + (q[1] - q_old1) * st) / dt;
    spin_prev = (q[3] + q[4] - q_old34) / dt;

    // ---- positions (symplectic Euler: new velocities)
    X += dt * q[0];
    Y += dt * q[1];
    phi += dt * q[2];
    th_r += dt * q[3];
    th_l += dt * q[4];
    }  // this file's physics
    if (segments) {
      double v1, w1, dv1, dw1;
      sref.at(t + dt, &v1, &w1, &dv1, &dw1);
      const double phi_mid = ref_phi + 0.25 * dt * (ref_w + w1);
      ref_x += dt * 0.5 * (ref_v + v1) * cos(phi_mid);
      ref_y += dt * 0.5 * (ref_v + v1) * sin(phi_mid);
      ref_phi += 0.5 * dt * (ref_w + w1);
      ref_v = v1; ref_w = w1; ref_dv = dv1; ref_dw = dw1;
    }
    if (!isfinite(X) || !isfinite(Y) || !isfinite(phi)) {
      snprintf(H.err, sizeof H.err, "state diverged at t = %g s", t);
      return -2;
    }
  }
  *n_tel = nt;
  *n_cam = nc;
  return 0;
}

}  // extern "C"
