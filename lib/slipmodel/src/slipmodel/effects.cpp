#if !defined(__AVR__)
#include <slipmodel/effects.h>

#include <math.h>
#include <string.h>

#include <slipmodel/params_table.h>

namespace slip {

namespace {
// The neutral values of the Table II.2 ones are the table's (params/params.json).
const EffectInfo kInfo[kEffectCount] = {
    {"friction_coefficient", 2, {"mu_s", "mu_k"}, {table::mu_s, table::mu_k}},
    {"wheel_radius", 1, {"r_eff", nullptr}, {table::r, 0.0}},
    {"track_width", 1, {"b_eff", nullptr}, {table::b, 0.0}},
    {"motor_back_emf", 1, {"ke_ratio", nullptr}, {1.0, 0.0}},
    {"driver_voltage_drop", 1, {"volts", nullptr}, {0.0, 0.0}},
    {"actuation_delay", 1, {"delay_s", nullptr}, {0.0, 0.0}},
    {"motor_lag", 1, {"tau_s", nullptr}, {0.0, 0.0}},
    {"axle_viscous", 1, {"c", nullptr}, {0.0, 0.0}},
    {"axle_coulomb", 1, {"torque", nullptr}, {0.0, 0.0}},
    {"caster_drag", 1, {"mu", nullptr}, {0.0, 0.0}},
    {"load_transfer", 1, {"h", nullptr}, {table::h, 0.0}},
    {"stribeck", 2, {"mu_k0", "v_s"}, {table::mu_k, 0.01}},
    {"deadband", 1, {"volts", nullptr}, {0.0, 0.0}},
    {"motor_gain_asymmetry", 1, {"ratio", nullptr}, {1.0, 0.0}},
    {"floor_slope", 1, {"rad", nullptr}, {0.0, 0.0}},
};
}  // namespace

const EffectInfo& effect_info(int id) { return kInfo[id]; }

int effect_id(const char* name) {
  if (name == nullptr) return -1;
  for (int i = 0; i < kEffectCount; ++i)
    if (strcmp(kInfo[i].name, name) == 0) return i;
  return -1;
}

int effect_param_index(int id, const char* param) {
  if (id < 0 || id >= kEffectCount || param == nullptr) return -1;
  for (int k = 0; k < kInfo[id].param_count; ++k)
    if (strcmp(kInfo[id].param_names[k], param) == 0) return k;
  return -1;
}

bool effect_param_valid(int id, int k, double v) {
  if (id < 0 || id >= kEffectCount || k < 0 || k >= kInfo[id].param_count) return false;
  if (!isfinite(v)) return false;
  switch (id) {
    case kWheelRadius:
    case kTrackWidth:
    case kMotorGainAsymmetry:
      return v > 0.0;
    case kStribeck:
      return k == 1 ? v > 0.0 : v >= 0.0;
    case kFloorSlope:
      return fabs(v) < 1.5707963267948966;
    case kLoadTransfer:
      return true;  // any height; negative models a centre of mass below the contact plane
    case kDriverVoltageDrop:
      return true;  // negative: the driver delivers more than the nominal supply
    default:  // coefficients, ratios, times, torques, deadband
      return v >= 0.0;
  }
}

Effects::Effects() { clear(); }

void Effects::clear() {
  for (int i = 0; i < kEffectCount; ++i) {
    enabled[i] = false;
    for (int k = 0; k < kMaxEffectParams; ++k) p[i][k] = kInfo[i].defaults[k];
  }
}

double Effects::get(EffectId id, int k) const {
  return enabled[id] ? p[id][k] : kInfo[id].defaults[k];
}

}  // namespace slip
#endif  // !__AVR__
