// C ABI over lib/slipmodel for Python (ctypes): the plant, its parameters, the effect vocabulary,
// normal forces and tau_max. Built into .build/host/libddrobot.so by host_tools/_build.py.
// Never crashes on bad input: unknown keys, NaN values and bad arrays give a negative return
// code and a message from sm_last_error(plant).
#include "slipmodel_capi.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include <slipmodel/effects.h>
#include <slipmodel/keys.h>
#include <slipmodel/motor.h>
#include <slipmodel/params.h>
#include <slipmodel/plant.h>
#include <slipmodel/traction.h>

namespace {

enum {
  SM_OK = 0,
  SM_ERR_KEY = -1,    // unknown key / effect / index
  SM_ERR_VALUE = -2,  // NaN, infinite or out-of-range value
  SM_ERR_ARG = -3,    // null pointer, bad n, bad mode
  SM_ERR_TIME = -4,   // time stamps not strictly increasing
};

struct Handle {
  slip::Plant plant;
  char err[256];
  Handle() : plant() { err[0] = '\0'; }
};

const char* const kCols[] = {"t_s",         "x_m",         "y_m",            "phi_rad",
                             "v_m_s",       "omega_rad_s", "theta_r_rad",    "theta_l_rad",
                             "dtheta_r_rad_s", "dtheta_l_rad_s", "tau_r_nm", "tau_l_nm",
                             "slip_r",      "slip_l",      "N_r",            "N_l",
                             "N_c",         "w_m_s",       "F_r_n",          "F_l_n",
                             "L_r_n",       "L_l_n",       "i_r_a",          "i_l_a"};
const int kColCount = sizeof(kCols) / sizeof(kCols[0]);
// The shortest span between two rows that the plant is stepped over (s): rows closer than a
// nanosecond are one instant that two clocks rounded apart (no recorder resolves it).
const double kMinSpan_s = 1e-9;

Handle* H(void* p) { return static_cast<Handle*>(p); }

void set_err(Handle* h, const char* fmt, const char* a, double x = 0.0, int i = 0) {
  if (h) snprintf(h->err, sizeof(h->err), fmt, a, x, i);
}

void fill_dynamic(const slip::Plant& pl, double* row) {
  const slip::PlantState& s = pl.state();
  row[10] = s.tau_r_nm;
  row[11] = s.tau_l_nm;
  row[14] = s.N_r;
  row[15] = s.N_l;
  row[16] = s.N_c;
  row[18] = s.F_r_n;
  row[19] = s.F_l_n;
  row[20] = s.L_r_n;
  row[21] = s.L_l_n;
  row[22] = pl.current_a(0);
  row[23] = pl.current_a(1);
}

void fill_kinematic(const slip::PlantState& s, double* row) {
  row[0] = s.t_s;
  row[1] = s.x_m;
  row[2] = s.y_m;
  row[3] = s.phi_rad;
  row[4] = s.v_m_s;
  row[5] = s.omega_rad_s;
  row[6] = s.theta_r_rad;
  row[7] = s.theta_l_rad;
  row[8] = s.dtheta_r_rad_s;
  row[9] = s.dtheta_l_rad_s;
  row[12] = s.slipping_r ? 1.0 : 0.0;
  row[13] = s.slipping_l ? 1.0 : 0.0;
  row[17] = s.w_m_s;
}

}  // namespace

extern "C" {

int sm_effect_count(void) { return slip::kEffectCount; }

const char* sm_effect_name(int i) {
  return (i >= 0 && i < slip::kEffectCount) ? slip::effect_info(i).name : nullptr;
}

int sm_effect_param_count(int i) {
  return (i >= 0 && i < slip::kEffectCount) ? slip::effect_info(i).param_count : SM_ERR_KEY;
}

const char* sm_effect_param_name(int i, int k) {
  if (i < 0 || i >= slip::kEffectCount || k < 0 || k >= slip::effect_info(i).param_count)
    return nullptr;
  return slip::effect_info(i).param_names[k];
}

double sm_effect_param_default(int i, int k) {
  if (i < 0 || i >= slip::kEffectCount || k < 0 || k >= slip::effect_info(i).param_count)
    return NAN;
  return slip::effect_info(i).defaults[k];
}

int sm_param_count(void) { return slip::param_key_count(); }
const char* sm_param_name(int i) { return slip::param_key_name(i); }

void* sm_plant_new(void) { return new Handle(); }

void sm_plant_free(void* p) { delete H(p); }

const char* sm_last_error(void* p) { return p ? H(p)->err : "null plant"; }

int sm_plant_set(void* p, const char* key, double v) {
  Handle* h = H(p);
  if (h == nullptr || key == nullptr) return SM_ERR_ARG;
  const int rc = slip::plant_set(h->plant, key, v);
  if (rc == slip::kKeyUnknown) set_err(h, "unknown key '%s'", key);
  else if (rc != slip::kKeyOk) set_err(h, "%s: bad value %g", key, v);
  return rc == slip::kKeyUnknown ? SM_ERR_KEY : (rc == slip::kKeyOk ? SM_OK : SM_ERR_VALUE);
}

int sm_plant_get(void* p, const char* key, double* out) {
  Handle* h = H(p);
  if (h == nullptr || key == nullptr || out == nullptr) return SM_ERR_ARG;
  if (slip::plant_get(h->plant, key, out) != slip::kKeyOk) {
    set_err(h, "unknown key '%s'", key);
    return SM_ERR_KEY;
  }
  return SM_OK;
}

int sm_plant_clear_effects(void* p) {
  if (p == nullptr) return SM_ERR_ARG;
  H(p)->plant.effects().clear();
  return SM_OK;
}

int sm_plant_reset(void* p, double x, double y, double phi) {
  Handle* h = H(p);
  if (h == nullptr) return SM_ERR_ARG;
  if (!isfinite(x) || !isfinite(y) || !isfinite(phi)) {
    set_err(h, "reset: start pose must be finite%s", "");
    return SM_ERR_VALUE;
  }
  h->plant.reset(x, y, phi);
  return SM_OK;
}

int sm_plant_set_velocity(void* p, double v_m_s, double w_m_s, double omega_rad_s,
                          double dtheta_r_rad_s, double dtheta_l_rad_s) {
  Handle* h = H(p);
  if (h == nullptr) return SM_ERR_ARG;
  if (!isfinite(v_m_s) || !isfinite(w_m_s) || !isfinite(omega_rad_s) || !isfinite(dtheta_r_rad_s) ||
      !isfinite(dtheta_l_rad_s)) {
    set_err(h, "set_velocity: velocities must be finite%s", "");
    return SM_ERR_VALUE;
  }
  h->plant.set_velocity(v_m_s, w_m_s, omega_rad_s, dtheta_r_rad_s, dtheta_l_rad_s);
  return SM_OK;
}

int sm_out_cols(void) { return kColCount; }

const char* sm_out_col_name(int i) { return (i >= 0 && i < kColCount) ? kCols[i] : nullptr; }

int sm_simulate(void* p, int mode, int n, const double* t_s, const double* in_r,
                const double* in_l, double dt_s, double* out) {
  Handle* h = H(p);
  if (h == nullptr) return SM_ERR_ARG;
  if (mode != 0 && mode != 1) { set_err(h, "simulate: mode must be 0 (torque) or 1 (duty)%s", ""); return SM_ERR_ARG; }
  if (n < 1 || t_s == nullptr || in_r == nullptr || in_l == nullptr || out == nullptr) {
    set_err(h, "simulate: need n >= 1 and non-null arrays%s", "");
    return SM_ERR_ARG;
  }
  if (!isfinite(dt_s) || !(dt_s > 0.0)) { set_err(h, "simulate: dt_s must be > 0, got %s%g", "", dt_s); return SM_ERR_VALUE; }
  // Validate everything before touching the plant: bad input loses nothing.
  for (int k = 0; k < n; ++k) {
    if (!isfinite(t_s[k])) { set_err(h, "simulate: t_s[%3$d] is %2$g%1$s", "", t_s[k], k); return SM_ERR_VALUE; }
    if (!isfinite(in_r[k])) { set_err(h, "simulate: in_r[%3$d] is %2$g%1$s", "", in_r[k], k); return SM_ERR_VALUE; }
    if (!isfinite(in_l[k])) { set_err(h, "simulate: in_l[%3$d] is %2$g%1$s", "", in_l[k], k); return SM_ERR_VALUE; }
    if (k > 0 && !(t_s[k] > t_s[k - 1])) {
      set_err(h, "simulate: t_s[%3$d] = %2$g is not greater than the previous time%1$s", "", t_s[k], k);
      return SM_ERR_TIME;
    }
  }
  slip::Plant& pl = h->plant;
  pl.set_time(t_s[0]);
  const int nc = kColCount;
  for (int k = 0; k < n; ++k) {
    double* row = out + static_cast<long>(k) * nc;
    fill_kinematic(pl.state(), row);
    row[0] = t_s[k];
    if (k == n - 1) {
      fill_dynamic(pl, row);
      break;
    }
    const double span = t_s[k + 1] - t_s[k];
    if (span < kMinSpan_s) {
      // two rows at one instant (a recorder's time and a tick time rounded apart): not
      // stepped, since a step that short turns the stick constraint's impulse into a traction
      // spike and can release a wheel that no torque released
      fill_dynamic(pl, row);
      pl.set_time(t_s[k + 1]);
      continue;
    }
    long steps = static_cast<long>(ceil(span / dt_s - 1e-9));
    if (steps < 1) steps = 1;
    const double hstep = span / static_cast<double>(steps);
    for (long j = 0; j < steps; ++j) {
      if (mode == 0)
        pl.step_torque(in_r[k], in_l[k], hstep);
      else
        pl.step_duty(in_r[k], in_l[k], hstep);
      if (j == 0) fill_dynamic(pl, row);
    }
    pl.set_time(t_s[k + 1]);  // no drift of the clock from summing steps
  }
  return SM_OK;
}

double sm_tau_max(void* p, int wheel) {
  if (p == nullptr || (wheel != 0 && wheel != 1)) return NAN;
  return H(p)->plant.tau_max_nm(wheel);
}

int sm_normal_forces(void* p, double* N_r, double* N_l, double* N_c) {
  if (p == nullptr || N_r == nullptr || N_l == nullptr || N_c == nullptr) return SM_ERR_ARG;
  const slip::NormalForces n = H(p)->plant.static_normal_forces();
  *N_r = n.N_r;
  *N_l = n.N_l;
  *N_c = n.N_c;
  return SM_OK;
}

}  // extern "C"
