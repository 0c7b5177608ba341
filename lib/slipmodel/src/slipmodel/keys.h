// String keys for the plant's parameters and effects, the names meta.json and the analyzer use:
// "robot.<Table II.2 name>", "motor.<name>", "<effect>.<param>", "<effect>.enabled", and the
// model setting "plant.spin_share" (Plant::set_spin_share, in [0, 1]; not a vocabulary name).
// Host only. The C ABI (host_tools/native/slipmodel_capi.cpp) and C++ hosts (the
// firmware-in-the-loop simulator) share this one table.
#ifndef SLIPMODEL_KEYS_H
#define SLIPMODEL_KEYS_H

#if !defined(__AVR__)

#include <slipmodel/plant.h>

namespace slip {

enum KeyStatus {
  kKeyOk = 0,
  kKeyUnknown = -1,   ///< no such key
  kKeyBadValue = -2,  ///< NaN, infinite, or outside the parameter's physical range
};

/// Number of "robot.*" and "motor.*" keys, and their names.
int param_key_count();
const char* param_key_name(int i);

/// Sets a key. "robot.*" and "motor.*" values must lie in the table's range (params/params.json,
/// SLIP_ROBOT_PARAMS / SLIP_MOTOR_PARAMS); effect parameters as effect_param_valid(). "<effect>.enabled" takes 0 (off) or anything else (on).
/// On error nothing changes.
int plant_set(Plant& plant, const char* key, double value);
/// Reads a key into *out.
int plant_get(const Plant& plant, const char* key, double* out);

}  // namespace slip

#endif  // !__AVR__
#endif  // SLIPMODEL_KEYS_H
