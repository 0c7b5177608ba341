// C ABI over lib/closedloop for Python (ctypes): the firmware's cascade (lib/control) in closed
// loop with the lib/slipmodel plant, stepped forward tick by tick (cl::Driver). Built into
// .build/host/libddrobot.so by host_tools/_build.py. Cost is linear in the run length: a
// call to cl_run continues from where the last one stopped.
//
// Use: h = cl_new(fixed, clamp); cl_set(h, key, value)...; cl_set_reference(h, ...);
// cl_reset(h, x, y, phi); cl_run(h, n, ticks, tick_cols, rows, row_cols) (again for more).
// Keys: the plant's own (slipmodel/keys.h: "robot.<p>", "motor.<p>", "<effect>.<param>",
// "<effect>.enabled"); the controller's nominal robot and motor "ctl.robot.<p>",
// "ctl.motor.<p>" and "ctl.clamp"; the schedule "loop.fixed_point", "loop.t0_s",
// "loop.inner_s", "loop.outer_every", "loop.ppr", "loop.plant_dt_s", "loop.rows_per_tick",
// "loop.actuator" (0 duty, 1 torque command). A ctl.* or loop.* key rebuilds the driver (plant
// parameters and effects are kept): call cl_reset after the keys.
// Never crashes on bad input: negative return codes and a message from cl_last_error(h).
#include "closedloop_capi.h"

#include "ctl_columns.h"
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <vector>

#include <closedloop/driver.h>
#include <slipmodel/keys.h>

namespace {

enum {
  CL_OK = 0,
  CL_ERR_KEY = -1,     // unknown key or reference kind
  CL_ERR_VALUE = -2,   // NaN, infinite or out-of-range value
  CL_ERR_ARG = -3,     // null pointer, bad count, wrong column count
  CL_ERR_CONFIG = -4,  // the configuration is not usable (see the message)
};

// Tick columns: time and counts, the controller's (the names of ctl_inner's columns), then
// the plant's at the tick (kPlantCols), then the tick's slip summary.
const char* const* const kCtlCols = ctlcols::kNames;
const int kCtlColCount = ctlcols::kCount;
const char* const kPlantCols[] = {"x_m", "y_m", "phi_rad", "v_m_s", "omega_rad_s", "theta_r_rad",
                                  "theta_l_rad", "dtheta_r_rad_s", "dtheta_l_rad_s", "tau_r_nm",
                                  "tau_l_nm", "slip_r", "slip_l"};
const int kPlantColCount = static_cast<int>(sizeof(kPlantCols) / sizeof(kPlantCols[0]));
const int kTickColCount = 3 + kCtlColCount + kPlantColCount + 2;
const int kRowColCount = 1 + kPlantColCount;

struct Handle {
  cl::DriverConfig cfg;
  cl::Driver* drv;
  std::vector<cl::DriveCommand> drive_cmds;  // cfg.drive_cmds points here
  char err[256];
  Handle() : cfg(), drv(new cl::Driver(cfg)) { err[0] = '\0'; }
  ~Handle() { delete drv; }
  // A new driver for cfg with the old plant's parameters and effects.
  int rebuild(const cl::DriverConfig& next) {
    const char* why = next.check();
    if (why[0]) {
      snprintf(err, sizeof err, "%s", why);
      return CL_ERR_CONFIG;
    }
    cl::Driver* d = new cl::Driver(next, drv->plant().robot(), drv->plant().motor());
    d->plant().effects() = drv->plant().effects();
    delete drv;
    drv = d;
    cfg = next;
    return CL_OK;
  }
};

Handle* H(void* p) { return static_cast<Handle*>(p); }

double* plant_row(const slip::PlantState& s, double* o) {
  const double v[] = {s.x_m, s.y_m, s.phi_rad, s.v_m_s, s.omega_rad_s, s.theta_r_rad, s.theta_l_rad,
                      s.dtheta_r_rad_s, s.dtheta_l_rad_s, s.tau_r_nm, s.tau_l_nm,
                      s.slipping_r ? 1.0 : 0.0, s.slipping_l ? 1.0 : 0.0};
  memcpy(o, v, sizeof v);
  return o + kPlantColCount;
}

void tick_row(const cl::TickOut& t, double* o) {
  const cl::CtlRow& c = t.ctl;
  const double v[] = {t.t_s, double(t.enc_r), double(t.enc_l),
                      c.pwm_r, c.pwm_l, c.tau_cmd_r, c.tau_cmd_l, c.tau_max_r, c.tau_max_l,
                      double(c.clamped_r), double(c.clamped_l), double(c.sat_r), double(c.sat_l),
                      c.omega_r, c.omega_l, c.x_odo_m, c.y_odo_m, c.phi_odo_rad, c.v_d_m_s,
                      c.omega_d_rad_s, c.e_x_m, c.e_y_m, c.e_phi_rad, double(c.odo_status),
                      c.pwm_slope_r, c.pwm_slope_l};
  memcpy(o, v, sizeof v);
  o = plant_row(t.plant, o + 3 + kCtlColCount);
  o[0] = t.slip_steps;
  o[1] = t.first_slip_t_s;
}

// "ctl.robot.<p>" / "ctl.motor.<p>": the plant's key table on a scratch plant (one table).
int set_ctl_param(Handle* h, cl::DriverConfig* next, const char* key, double v) {
  slip::Plant scratch(next->ctl.robot, next->ctl.motor);
  const int rc = slip::plant_set(scratch, key, v);
  if (rc == slip::kKeyUnknown) return CL_ERR_KEY;
  if (rc != slip::kKeyOk) {
    snprintf(h->err, sizeof h->err, "ctl.%s: bad value %g", key, v);
    return CL_ERR_VALUE;
  }
  next->ctl = ctl::make_control_config(scratch.robot(), scratch.motor(), next->ctl.gains,
                                       next->ctl.clamp_enabled, next->ctl.variant);
  return CL_OK;
}

int set_loop(cl::DriverConfig* c, const char* k, double v) {
  const bool whole = v == floor(v) && fabs(v) < 2e9;
  if (strcmp(k, "fixed_point") == 0) c->fixed_point = v != 0.0;
  else if (strcmp(k, "t0_s") == 0) c->t0_s = v;
  else if (strcmp(k, "inner_s") == 0) c->inner_s = v;
  else if (strcmp(k, "plant_dt_s") == 0) c->plant_dt_s = v;
  else if (strcmp(k, "outer_every") == 0 && whole) c->outer_every = static_cast<int>(v);
  else if (strcmp(k, "ppr") == 0 && whole) c->ppr = static_cast<int32_t>(v);
  else if (strcmp(k, "rows_per_tick") == 0 && whole) c->rows_per_tick = static_cast<int>(v);
  else if (strcmp(k, "duty_ramp") == 0) c->duty_ramp = v != 0.0;
  else if (strcmp(k, "actuator") == 0 && (v == 0.0 || v == 1.0))
    c->actuator = v == 0.0 ? cl::Actuator::kDuty : cl::Actuator::kTorque;
  else if (strcmp(k, "outer_every") == 0 || strcmp(k, "ppr") == 0 || strcmp(k, "rows_per_tick") == 0 ||
           strcmp(k, "actuator") == 0)
    return CL_ERR_VALUE;
  else return CL_ERR_KEY;
  return CL_OK;
}

}  // namespace

extern "C" {

void* cl_new(int fixed_point, int clamp_enabled) {
  Handle* h = new Handle();
  cl::DriverConfig c = h->cfg;
  c.fixed_point = fixed_point != 0;
  c.ctl.clamp_enabled = clamp_enabled != 0;
  h->rebuild(c);
  return h;
}

void cl_free(void* h) { delete H(h); }

const char* cl_last_error(void* h) { return h ? H(h)->err : "null handle"; }

int cl_tick_col_count(void) { return kTickColCount; }

const char* cl_tick_col_name(int i) {
  if (i < 0 || i >= kTickColCount) return nullptr;
  const char* const head[] = {"t_s", "enc_r", "enc_l"};
  if (i < 3) return head[i];
  if ((i -= 3) < kCtlColCount) return kCtlCols[i];
  if ((i -= kCtlColCount) < kPlantColCount) return kPlantCols[i];
  return i == kPlantColCount ? "slip_steps" : "first_slip_t_s";
}

int cl_row_col_count(void) { return kRowColCount; }

const char* cl_row_col_name(int i) {
  if (i == 0) return "t_s";
  return (i > 0 && i < kRowColCount) ? kPlantCols[i - 1] : nullptr;
}

/// Sets a key (see the header comment).
int cl_set(void* p, const char* key, double value) {
  if (!p || !key) return CL_ERR_ARG;
  Handle* h = H(p);
  if (!isfinite(value)) {
    snprintf(h->err, sizeof h->err, "value for %s is not finite", key);
    return CL_ERR_VALUE;
  }
  cl::DriverConfig next = h->cfg;
  int rc = CL_ERR_KEY;
  if (strncmp(key, "ctl.", 4) == 0) {
    const char* k = key + 4;
    if (strcmp(k, "clamp") == 0) {
      next.ctl.clamp_enabled = value != 0.0;
      rc = CL_OK;
    } else if (strncmp(k, "gain.", 5) == 0) {  // ctl.gain.k_x ... k_ia (ctl_set's gain keys)
      const char* g = k + 5;
      ctl::Gains gn = next.ctl.gains;
      float* const f[] = {&gn.k_x, &gn.k_y, &gn.k_phi, &gn.k_l, &gn.k_a, &gn.k_il, &gn.k_ia};
      const char* const names[] = {"k_x", "k_y", "k_phi", "k_l", "k_a", "k_il", "k_ia"};
      for (int i = 0; i < 7; ++i) {
        if (strcmp(g, names[i]) != 0) continue;
        if (value < 0.0) {
          snprintf(h->err, sizeof h->err, "%s must be >= 0", key);
          return CL_ERR_VALUE;
        }
        *f[i] = static_cast<float>(value);
        next.ctl = ctl::make_control_config(next.ctl.robot, next.ctl.motor, gn,
                                            next.ctl.clamp_enabled, next.ctl.variant);
        rc = CL_OK;
      }
    } else if (strcmp(k, "controller") == 0) {  // 0 improved, 1 thesis (ctl_set's key)
      if (value != 0.0 && value != 1.0) {
        snprintf(h->err, sizeof h->err, "ctl.controller must be 0 (improved) or 1 (thesis)");
        return CL_ERR_VALUE;
      }
      const ctl::Variant v = static_cast<ctl::Variant>(static_cast<uint8_t>(value));
      next.ctl = ctl::make_control_config(next.ctl.robot, next.ctl.motor, ctl::gains_for(v),
                                          next.ctl.clamp_enabled, v);
      rc = CL_OK;
    } else if (strncmp(k, "robot.", 6) == 0 || strncmp(k, "motor.", 6) == 0) {
      rc = set_ctl_param(h, &next, k, value);
      if (rc == CL_ERR_VALUE) return rc;
    }
  } else if (strncmp(key, "loop.", 5) == 0) {
    rc = set_loop(&next, key + 5, value);
    if (rc == CL_ERR_VALUE) {
      snprintf(h->err, sizeof h->err, "%s: bad value %g", key, value);
      return rc;
    }
  } else {
    rc = slip::plant_set(h->drv->plant(), key, value);
    if (rc == slip::kKeyOk) return CL_OK;
    if (rc != slip::kKeyUnknown) {
      snprintf(h->err, sizeof h->err, "%s: bad value %g", key, value);
      return CL_ERR_VALUE;
    }
    rc = CL_ERR_KEY;
  }
  if (rc == CL_ERR_KEY) {
    snprintf(h->err, sizeof h->err, "unknown key %s", key);
    return rc;
  }
  return h->rebuild(next);
}

/// Reference: kind 0 line, 1 arc, 2 figure eight; accel m/s^2, cruise m/s, signed radius m.
int cl_set_reference(void* p, int kind, double accel_m_s2, double cruise_m_s, double radius_m) {
  if (!p) return CL_ERR_ARG;
  Handle* h = H(p);
  if (kind < 0 || kind > 2) {
    snprintf(h->err, sizeof h->err, "unknown reference kind %d", kind);
    return CL_ERR_KEY;
  }
  cl::DriverConfig next = h->cfg;
  next.drive = false;
  next.ref = ctl::ReferenceSpec{static_cast<ctl::PathKind>(kind), static_cast<float>(accel_m_s2),
                                static_cast<float>(cruise_m_s), static_cast<float>(radius_m)};
  if (!isfinite(accel_m_s2) || !isfinite(cruise_m_s) || !isfinite(radius_m) || !next.ref.valid()) {
    snprintf(h->err, sizeof h->err, "invalid reference (accel in (0,20], cruise in [0,4], |R| in [0.05,100])");
    return CL_ERR_VALUE;
  }
  return h->rebuild(next);
}

/// Drive mode instead of a profile (cl_set_reference switches back): acceleration limits and
/// n commands (board time s, v m/s, omega rad/s; sorted by time; v and omega are whole mm/s and
/// mrad/s as the Drive message carries them, within its ranges).
int cl_set_drive(void* p, double accel_m_s2, double alpha_rad_s2, int n, const double* t_s,
                 const double* v_m_s, const double* omega_rad_s) {
  if (!p || n < 0 || (n > 0 && (!t_s || !v_m_s || !omega_rad_s))) return CL_ERR_ARG;
  Handle* h = H(p);
  std::vector<cl::DriveCommand> cmds(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    const double v = v_m_s[i] * 1e3, w = omega_rad_s[i] * 1e3;
    if (!isfinite(t_s[i]) || !isfinite(v) || !isfinite(w) || fabs(v) > 4000.0 || fabs(w) > 15000.0) {
      snprintf(h->err, sizeof h->err, "drive command %d: time, v or omega not finite or out of range", i);
      return CL_ERR_VALUE;
    }
    cmds[static_cast<size_t>(i)] = cl::DriveCommand{t_s[i], static_cast<int16_t>(lround(v)),
                                                    static_cast<int16_t>(lround(w))};
  }
  if (!isfinite(accel_m_s2) || !isfinite(alpha_rad_s2)) {
    snprintf(h->err, sizeof h->err, "drive limits not finite");
    return CL_ERR_VALUE;
  }
  std::vector<cl::DriveCommand> old;
  old.swap(h->drive_cmds);
  h->drive_cmds.swap(cmds);
  cl::DriverConfig next = h->cfg;
  next.drive = true;
  next.drive_limits = ctl::DriveLimits{static_cast<float>(accel_m_s2), static_cast<float>(alpha_rad_s2)};
  next.drive_cmds = h->drive_cmds.empty() ? nullptr : h->drive_cmds.data();
  next.n_drive = n;
  const int rc = h->rebuild(next);
  if (rc != CL_OK) h->drive_cmds.swap(old);  // the driver still uses the old list
  return rc;
}

/// Plant at rest at (x, y, phi) at time loop.t0_s, encoders 0, controller reset; tick 0 next.
int cl_reset(void* p, double x_m, double y_m, double phi_rad) {
  if (!p) return CL_ERR_ARG;
  Handle* h = H(p);
  if (!isfinite(x_m) || !isfinite(y_m) || !isfinite(phi_rad) || fabs(x_m) > 2000.0 || fabs(y_m) > 2000.0) {
    snprintf(h->err, sizeof h->err, "start pose must be finite and within +-2000 m");
    return CL_ERR_VALUE;
  }
  h->drv->reset(x_m, y_m, phi_rad);
  return CL_OK;
}

/// Runs n ticks: ticks[n][tick_cols] (tick_cols = cl_tick_col_count()); rows, when not null,
/// [n * loop.rows_per_tick][row_cols] (row_cols = cl_row_col_count()). Returns 0.
int cl_run(void* p, int n, double* ticks, int tick_cols, double* rows, int row_cols) {
  if (!p) return CL_ERR_ARG;
  Handle* h = H(p);
  if (n < 0 || !ticks || tick_cols != kTickColCount || (rows && row_cols != kRowColCount)) {
    snprintf(h->err, sizeof h->err, "cl_run: need n >= 0, a tick array of %d columns and a row array "
             "of %d columns or none", kTickColCount, kRowColCount);
    return CL_ERR_ARG;
  }
  const int m = h->cfg.rows_per_tick;
  slip::PlantState buf[16];
  slip::PlantState* st = m <= 16 ? buf : new slip::PlantState[m];
  for (int k = 0; k < n; ++k) {
    tick_row(h->drv->step(rows ? st : nullptr), ticks + static_cast<long>(k) * kTickColCount);
    if (!rows) continue;
    for (int j = 0; j < m; ++j) {
      double* o = rows + (static_cast<long>(k) * m + j) * kRowColCount;
      o[0] = st[j].t_s;
      plant_row(st[j], o + 1);
    }
  }
  if (st != buf) delete[] st;
  return CL_OK;
}

/// The plant now (after the last tick): a row of cl_row_col_count() columns (torques and forces
/// of the last Euler step).
int cl_state(void* p, double* out, int n) {
  if (!p || !out || n != kRowColCount) return CL_ERR_ARG;
  const slip::PlantState& s = H(p)->drv->plant().state();
  out[0] = s.t_s;
  plant_row(s, out + 1);
  return CL_OK;
}

}  // extern "C"
