// C ABI over lib/control for Python (ctypes) and for the independent truth simulator: the
// cascade (float or fixed point) and its references, driven exactly as the firmware drives it
// (encoder counts in, duties out). Built into .build/host/libddrobot.so by host_tools/_build.py.
//
// Self-describing: ctl_describe() returns a JSON document listing the settable keys with their
// defaults and units, the reference kinds and the output columns of ctl_inner(); the column
// order is also available as ctl_column_count()/ctl_column_name(i). pwm_slope_r/l: duty added
// per millisecond over the coming tick (the firmware ramps the duty by it every millisecond).
// Never crashes on bad input: unknown keys, NaN values, null pointers and short arrays give a
// negative return code and a message from ctl_last_error(h).
//
// Typical replay loop (one tick = 25 ms):
//   h = ctl_new(fixed, clamp); ctl_set_reference(h, kind, accel, cruise, radius);
//   ctl_reset(h, enc_r0, enc_l0, x0, y0, phi0);
//   each tick k: ctl_inner(h, enc_r, enc_l, 0.025, row, n); if k even: ctl_outer(h, k*0.025)
#include "control_capi.h"

#include "ctl_columns.h"
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <control/cascade.h>
#include <control/cascade_q.h>
#include <control/odometry.h>
#include <control/reference.h>
#include <protocol/messages.h>  // the firmware's task periods
#include <slipmodel/params.h>

namespace {

enum {
  CTL_OK = 0,
  CTL_ERR_KEY = -1,    // unknown key or reference kind
  CTL_ERR_VALUE = -2,  // NaN, infinite or out-of-range value
  CTL_ERR_ARG = -3,    // null pointer, short output array
  CTL_ERR_CONFIG = -4, // the configuration does not convert to fixed point
};

const char* const* const kCols = ctlcols::kNames;
const int kColCount = ctlcols::kCount;

// Settable keys: the table's robot and motor parameters (params/params.json, with their ranges),
// the gains, the clamp switch, the velocity-loop variant ("controller": 0 improved, 1 thesis;
// setting it loads that variant's default gains, which later "k_*" keys may override).
struct ParamKey {
  const char* name;
  const char* unit;
  double slip::RobotParams::*robot;
  double slip::MotorParams::*motor;
  double lo, hi;
};
#define CTL_ROBOT_KEY(name, def, lo, hi, unit, rf) {#name, unit, &slip::RobotParams::name, nullptr, lo, hi},
#define CTL_MOTOR_KEY(name, def, lo, hi, unit, rf) {#name, unit, nullptr, &slip::MotorParams::name, lo, hi},
const ParamKey kParamKeys[] = {SLIP_ROBOT_PARAMS(CTL_ROBOT_KEY) SLIP_MOTOR_PARAMS(CTL_MOTOR_KEY)};
#undef CTL_ROBOT_KEY
#undef CTL_MOTOR_KEY
const int kParamKeyCount = static_cast<int>(sizeof(kParamKeys) / sizeof(kParamKeys[0]));

struct GainKey {
  const char* name;
  const char* unit;
  float ctl::Gains::*gain;
};
const GainKey kGainKeys[] = {{"k_x", "1/s", &ctl::Gains::k_x},   {"k_y", "1/m^2", &ctl::Gains::k_y},
                             {"k_phi", "1/s", &ctl::Gains::k_phi}, {"k_l", "N s/m", &ctl::Gains::k_l},
                             {"k_a", "N m s", &ctl::Gains::k_a},   {"k_il", "N/m", &ctl::Gains::k_il},
                             {"k_ia", "N m", &ctl::Gains::k_ia}};
const int kGainKeyCount = static_cast<int>(sizeof(kGainKeys) / sizeof(kGainKeys[0]));

struct Handle {
  bool fixed;
  slip::RobotParams robot;
  slip::MotorParams motor;
  ctl::Gains gains;
  bool clamp;
  ctl::Variant variant;
  ctl::ReferenceSpec ref;
  ctl::ControlConfig cfg;
  ctl::ControlConfigQ cfg_q;
  ctl::ReferenceSpecQ ref_q;
  ctl::Controller fc;
  ctl::ControllerQ qc;
  char err[256];

  Handle(bool fixed_point, bool clamp_on)
      : fixed(fixed_point),
        robot(),
        motor(),
        gains(ctl::default_gains()),
        clamp(clamp_on),
        variant(ctl::Variant::kImproved),
        ref{ctl::PathKind::kLine, 1.0f, 0.0f, 0.0f},
        cfg(ctl::make_control_config(robot, motor, gains, clamp, variant)),
        cfg_q(cfg),
        ref_q(ref),
        fc(cfg),
        qc(cfg_q) {
    err[0] = '\0';
  }
  const ParamKey* param_key(const char* k) const {
    for (int i = 0; i < kParamKeyCount; ++i)
      if (strcmp(k, kParamKeys[i].name) == 0) return &kParamKeys[i];
    return nullptr;
  }
  double* field(const char* k) {
    const ParamKey* pk = param_key(k);
    if (!pk) return nullptr;
    return pk->robot ? &(robot.*pk->robot) : &(motor.*pk->motor);
  }
  float* gain(const char* k) {
    for (int i = 0; i < kGainKeyCount; ++i)
      if (strcmp(k, kGainKeys[i].name) == 0) return &(gains.*kGainKeys[i].gain);
    return nullptr;
  }
  // Rebuild both configurations (the controllers are reset).
  int rebuild() {
    cfg = ctl::make_control_config(robot, motor, gains, clamp, variant);
    cfg_q = ctl::ControlConfigQ(cfg);
    fc = ctl::Controller(cfg);
    qc = ctl::ControllerQ(cfg_q);
    if (fixed && !cfg_q.ok) {
      snprintf(err, sizeof err, "configuration does not fit the fixed-point formats");
      return CTL_ERR_CONFIG;
    }
    return CTL_OK;
  }
};

Handle* H(void* p) { return static_cast<Handle*>(p); }
bool is_fin(double x) { return isfinite(x) != 0; }
uint32_t to_b32(double rad) {
  const double turns = rad / (2.0 * 3.14159265358979323846);
  return static_cast<uint32_t>(static_cast<int64_t>(llround((turns - floor(turns)) * 4294967296.0)));
}
double from_b32(uint32_t a) { return static_cast<int32_t>(a) * (2.0 * 3.14159265358979323846 / 4294967296.0); }

}  // namespace

extern "C" {

int ctl_abi_version(void) { return 1; }

/// JSON: keys (name, unit, default), reference kinds, output columns, formats.
const char* ctl_describe(void) {
  static char buf[4096];
  if (buf[0]) return buf;
  Handle tmp(false, true);
  int n = snprintf(buf, sizeof buf, "{\"abi\": 1, \"keys\": [");
  const int total = kParamKeyCount + kGainKeyCount + 2;
  for (int i = 0; i < total && n < static_cast<int>(sizeof buf); ++i) {
    const char* name;
    const char* unit;
    double def;
    if (i < kParamKeyCount) {
      name = kParamKeys[i].name;
      unit = kParamKeys[i].unit;
      def = *tmp.field(name);
    } else if (i < kParamKeyCount + kGainKeyCount) {
      name = kGainKeys[i - kParamKeyCount].name;
      unit = kGainKeys[i - kParamKeyCount].unit;
      def = *tmp.gain(name);
    } else if (i == total - 2) {
      name = "clamp";
      unit = "0/1";
      def = 1.0;
    } else {
      name = "controller";
      unit = "0 improved, 1 thesis";
      def = static_cast<double>(static_cast<uint8_t>(tmp.variant));
    }
    n += snprintf(buf + n, sizeof buf - n, "%s{\"name\": \"%s\", \"unit\": \"%s\", \"default\": %.9g}",
                  i ? ", " : "", name, unit, def);
  }
  n += snprintf(buf + n, sizeof buf - n,
                "], \"reference_kinds\": {\"line\": 0, \"arc\": 1, \"figure_eight\": 2}, "
                "\"periods_s\": {\"inner\": %.9g, \"outer\": %.9g}, \"encoder_ppr\": %ld, \"columns\": [",
                proto::kInnerPeriodUs * 1e-6, proto::kOuterPeriodUs * 1e-6, static_cast<long>(slip::kEncoderPpr));
  for (int i = 0; i < kColCount && n < static_cast<int>(sizeof buf); ++i)
    n += snprintf(buf + n, sizeof buf - n, "%s\"%s\"", i ? ", " : "", kCols[i]);
  if (n < static_cast<int>(sizeof buf)) snprintf(buf + n, sizeof buf - n, "]}");
  return buf;
}

int ctl_column_count(void) { return kColCount; }
const char* ctl_column_name(int i) { return (i >= 0 && i < kColCount) ? kCols[i] : nullptr; }

/// New controller with Table II.2, the datasheet motor and the default gains.
void* ctl_new(int fixed_point, int clamp_enabled) { return new Handle(fixed_point != 0, clamp_enabled != 0); }
void ctl_free(void* h) { delete H(h); }
const char* ctl_last_error(void* h) { return h ? H(h)->err : "null handle"; }

/// Set a key (see ctl_describe). Rebuilds the configuration and resets the controller.
int ctl_set(void* h, const char* key, double value) {
  if (!h || !key) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (!is_fin(value)) {
    snprintf(p->err, sizeof p->err, "value for %s is not finite", key);
    return CTL_ERR_VALUE;
  }
  if (double* f = p->field(key)) {
    const ParamKey* pk = p->param_key(key);
    if (value < pk->lo || value > pk->hi) {
      snprintf(p->err, sizeof p->err, "%s = %g outside [%g, %g]", key, value, pk->lo, pk->hi);
      return CTL_ERR_VALUE;
    }
    *f = value;
  } else if (float* g = p->gain(key)) {
    if (value < 0.0) {
      snprintf(p->err, sizeof p->err, "gain %s must be >= 0", key);
      return CTL_ERR_VALUE;
    }
    *g = static_cast<float>(value);
  } else if (strcmp(key, "clamp") == 0) {
    p->clamp = value != 0.0;
  } else if (strcmp(key, "controller") == 0) {
    if (value != 0.0 && value != 1.0) {
      snprintf(p->err, sizeof p->err, "controller must be 0 (improved) or 1 (thesis)");
      return CTL_ERR_VALUE;
    }
    p->variant = static_cast<ctl::Variant>(static_cast<uint8_t>(value));
    p->gains = ctl::gains_for(p->variant);
  } else {
    snprintf(p->err, sizeof p->err, "unknown key %s", key);
    return CTL_ERR_KEY;
  }
  return p->rebuild();
}

int ctl_get(void* h, const char* key, double* out) {
  if (!h || !key || !out) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (double* f = p->field(key)) *out = *f;
  else if (float* g = p->gain(key)) *out = *g;
  else if (strcmp(key, "clamp") == 0) *out = p->clamp ? 1.0 : 0.0;
  else if (strcmp(key, "controller") == 0) *out = static_cast<double>(static_cast<uint8_t>(p->variant));
  else if (strcmp(key, "ff.m_kg") == 0) *out = p->cfg.m_ff_kg;        // read-only: the variant's
  else if (strcmp(key, "ff.I_kgm2") == 0) *out = p->cfg.I_ff_kgm2;    // feed-forward mass, inertia
  else {
    snprintf(p->err, sizeof p->err, "unknown key %s", key);
    return CTL_ERR_KEY;
  }
  return CTL_OK;
}

/// Reference: kind 0 line, 1 arc, 2 figure eight; accel m/s^2, cruise m/s, signed radius m.
int ctl_set_reference(void* h, int kind, double accel_m_s2, double cruise_m_s, double radius_m) {
  if (!h) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (kind < 0 || kind > 2) {
    snprintf(p->err, sizeof p->err, "unknown reference kind %d", kind);
    return CTL_ERR_KEY;
  }
  const ctl::ReferenceSpec s{static_cast<ctl::PathKind>(kind), static_cast<float>(accel_m_s2),
                             static_cast<float>(cruise_m_s), static_cast<float>(radius_m)};
  if (!is_fin(accel_m_s2) || !is_fin(cruise_m_s) || !is_fin(radius_m) || !s.valid()) {
    snprintf(p->err, sizeof p->err, "invalid reference (accel in (0,20], cruise in [0,4], |R| in [0.05,100])");
    return CTL_ERR_VALUE;
  }
  p->ref = s;
  p->ref_q = ctl::ReferenceSpecQ(s);
  return CTL_OK;
}

/// Reference sample at t_s: out[7] = x, y, phi, v, omega, dv, domega (fixed handles sample the
/// fixed-point reference at the nearest millisecond).
int ctl_reference(void* h, double t_s, double* out, int n) {
  if (!h || !out || n < 7) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (!is_fin(t_s) || t_s < 0.0) {
    snprintf(p->err, sizeof p->err, "t_s must be finite and >= 0");
    return CTL_ERR_VALUE;
  }
  if (p->fixed) {
    const ctl::RefSampleQ r = ctl::reference_at_q(p->ref_q, static_cast<uint32_t>(llround(fmin(t_s, 32000.0) * 1000.0)));
    const double v[7] = {r.x_q20 / 1048576.0, r.y_q20 / 1048576.0, from_b32(r.phi_b32), r.v_q12 / 4096.0,
                         r.omega_q11 / 2048.0, r.dv_q12 / 4096.0, r.domega_q11 / 2048.0};
    memcpy(out, v, sizeof v);
  } else {
    const ctl::RefSample r = ctl::reference_at(p->ref, static_cast<float>(t_s));
    const double v[7] = {r.x_m, r.y_m, r.phi_rad, r.v_m_s, r.omega_rad_s, r.dv_m_s2, r.domega_rad_s2};
    memcpy(out, v, sizeof v);
  }
  return CTL_OK;
}

/// Start at pose (x, y, phi) with the encoders reading (enc_r, enc_l).
int ctl_reset(void* h, int32_t enc_r, int32_t enc_l, double x_m, double y_m, double phi_rad) {
  if (!h) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (!is_fin(x_m) || !is_fin(y_m) || !is_fin(phi_rad) || fabs(x_m) > 2000.0 || fabs(y_m) > 2000.0) {
    snprintf(p->err, sizeof p->err, "start pose must be finite and within +-2000 m");
    return CTL_ERR_VALUE;
  }
  p->fc.reset(enc_r, enc_l, ctl::Pose{static_cast<float>(x_m), static_cast<float>(y_m), static_cast<float>(phi_rad)});
  p->qc.reset(enc_r, enc_l, ctl::PoseQ{static_cast<int32_t>(llround(x_m * 1048576.0)),
                                       static_cast<int32_t>(llround(y_m * 1048576.0)), to_b32(phi_rad)});
  return CTL_OK;
}

/// Outer step with the reference at t_s (call after the inner step of the same tick).
int ctl_outer(void* h, double t_s) {
  if (!h) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (!is_fin(t_s) || t_s < 0.0) {
    snprintf(p->err, sizeof p->err, "t_s must be finite and >= 0");
    return CTL_ERR_VALUE;
  }
  if (p->fixed) p->qc.outer_step(ctl::reference_at_q(p->ref_q, static_cast<uint32_t>(llround(fmin(t_s, 32000.0) * 1000.0))));
  else p->fc.outer_step(ctl::reference_at(p->ref, static_cast<float>(t_s)));
  return CTL_OK;
}

}  // extern "C"

namespace {  // helpers of ctl_inner and ctl_start (internal linkage: not exported)
// A fixed-point handle whose configuration did not convert refuses to step (error set).
bool fixed_config_ok(Handle* p) {
  if (!p->fixed || p->cfg_q.ok) return true;
  snprintf(p->err, sizeof p->err, "configuration does not fit the fixed-point formats");
  return false;
}

// The columns (ctl_column_name) of the controller's state after an inner step or the start.
int fill_columns(Handle* p, double* out) {
  if (p->fixed) {
    const ctl::InnerOutQ& o = p->qc.inner();
    const ctl::KinematicOutQ& k = p->qc.kinematic();
    const ctl::OdometryQ& od = p->qc.odometry();
    const double v[] = {o.pwm_r_q15 / 32768.0, o.pwm_l_q15 / 32768.0, o.tau_r_q16 / 65536.0, o.tau_l_q16 / 65536.0,
                        o.tau_max_r_q16 / 65536.0, o.tau_max_l_q16 / 65536.0, double(o.clamped_r), double(o.clamped_l),
                        double(o.sat_r), double(o.sat_l), od.omega_r_q8() / 256.0, od.omega_l_q8() / 256.0,
                        od.pose().x_q20 / 1048576.0, od.pose().y_q20 / 1048576.0, from_b32(od.pose().phi_b32),
                        k.v_d_q12 / 4096.0, k.omega_d_q11 / 2048.0, k.e_x_q12 / 4096.0, k.e_y_q12 / 4096.0,
                        from_b32(static_cast<uint32_t>(k.e_phi_b32)), double(static_cast<int>(o.odo)),
                        o.slope_r_q15 / 32768.0, o.slope_l_q15 / 32768.0};
    memcpy(out, v, sizeof v);
    return static_cast<int>(o.odo);
  }
  const ctl::InnerOut& o = p->fc.inner();
  const ctl::KinematicOut& k = p->fc.kinematic();
  const ctl::Odometry& od = p->fc.odometry();
  const double v[] = {o.pwm_r, o.pwm_l, o.tau_r_nm, o.tau_l_nm, o.tau_max_r_nm, o.tau_max_l_nm,
                      double(o.clamped_r), double(o.clamped_l), double(o.sat_r), double(o.sat_l),
                      od.omega_r_rad_s(), od.omega_l_rad_s(), od.pose().x_m, od.pose().y_m, od.pose().phi_rad,
                      k.v_d_m_s, k.omega_d_rad_s, k.e_x_m, k.e_y_m, k.e_phi_rad, double(static_cast<int>(o.odo)),
                      o.pwm_slope_r, o.pwm_slope_l};
  memcpy(out, v, sizeof v);
  return static_cast<int>(o.odo);
}
}  // namespace

extern "C" {

/// Inner step: cumulative counts, dt in seconds; fills out[0..n) with the columns (see
/// ctl_column_name). Returns the odometry status (0 ok, > 0 a reported input problem).
int ctl_inner(void* h, int32_t enc_r, int32_t enc_l, double dt_s, double* out, int n) {
  if (!h || !out || n < kColCount) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (!is_fin(dt_s) || dt_s <= 0.0 || dt_s > 1.0) {
    snprintf(p->err, sizeof p->err, "dt_s must be in (0, 1] s");
    return CTL_ERR_VALUE;
  }
  if (!fixed_config_ok(p)) return CTL_ERR_CONFIG;
  if (p->fixed) {
    p->qc.inner_step(enc_r, enc_l, static_cast<uint32_t>(llround(dt_s * 1e6)));
  } else {
    p->fc.inner_step(enc_r, enc_l, static_cast<float>(dt_s));
  }
  return fill_columns(p, out);
}

/// Start of an experiment at pose (x, y, phi) with the encoders reading (enc_r, enc_l): reset,
/// the outer step with the reference at t = 0 and the first command from rest (the start tick
/// of the firmware and lib/closedloop; the inner steps follow with ctl_inner, the outer steps
/// after every second of them). Fills out[0..n) like ctl_inner.
int ctl_start(void* h, int32_t enc_r, int32_t enc_l, double x_m, double y_m, double phi_rad, double* out,
              int n) {
  if (!h || !out || n < kColCount) return CTL_ERR_ARG;
  Handle* p = H(h);
  if (!is_fin(x_m) || !is_fin(y_m) || !is_fin(phi_rad) || fabs(x_m) > 2000.0 || fabs(y_m) > 2000.0) {
    snprintf(p->err, sizeof p->err, "start pose must be finite and within +-2000 m");
    return CTL_ERR_VALUE;
  }
  if (!fixed_config_ok(p)) return CTL_ERR_CONFIG;
  if (p->fixed) {
    p->qc.start(enc_r, enc_l, ctl::PoseQ{static_cast<int32_t>(llround(x_m * 1048576.0)),
                                         static_cast<int32_t>(llround(y_m * 1048576.0)), to_b32(phi_rad)},
                ctl::reference_at_q(p->ref_q, 0));
  } else {
    p->fc.start(enc_r, enc_l, ctl::Pose{static_cast<float>(x_m), static_cast<float>(y_m), static_cast<float>(phi_rad)},
                ctl::reference_at(p->ref, 0.0f));
  }
  return fill_columns(p, out);
}

// Encoder odometry (III.1-III.4, lib/control's float ctl::Odometry) over a series of cumulative
// counts: the pose after each sample, starting from (x0, y0, phi0) at sample 0. Lets host tools
// compare odometry with the firmware's own formula instead of re-implementing it.
// Returns the number of samples whose update reported a problem (0 normally), or a negative
// error code (bad arguments, non-positive r, b or ppr).
int ctl_odometry_series(double r_m, double b_m, int32_t counts_per_rev, int n,
                        const int32_t* enc_r, const int32_t* enc_l, const double* t_s,
                        double x0_m, double y0_m, double phi0_rad,
                        double* x_m, double* y_m, double* phi_rad) {
  if (n < 1 || !enc_r || !enc_l || !t_s || !x_m || !y_m || !phi_rad) return CTL_ERR_ARG;
  if (!(r_m > 0.0) || !(b_m > 0.0) || counts_per_rev <= 0 || !isfinite(x0_m) ||
      !isfinite(y0_m) || !isfinite(phi0_rad))
    return CTL_ERR_VALUE;
  const ctl::OdometryConfig cfg{static_cast<float>(r_m), static_cast<float>(b_m), counts_per_rev};
  ctl::Odometry odo(cfg);
  odo.reset(enc_r[0], enc_l[0],
            ctl::Pose{static_cast<float>(x0_m), static_cast<float>(y0_m), static_cast<float>(phi0_rad)});
  x_m[0] = x0_m;
  y_m[0] = y0_m;
  phi_rad[0] = phi0_rad;
  int problems = 0;
  for (int k = 1; k < n; ++k) {
    if (odo.update(enc_r[k], enc_l[k], static_cast<float>(t_s[k] - t_s[k - 1])) != ctl::OdoStatus::kOk)
      ++problems;
    x_m[k] = odo.pose().x_m;
    y_m[k] = odo.pose().y_m;
    phi_rad[k] = odo.pose().phi_rad;
  }
  return problems;
}

}  // extern "C"
