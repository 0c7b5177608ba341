#if !defined(__AVR__)
#include <slipmodel/keys.h>

#include <math.h>
#include <string.h>

namespace slip {

namespace {

struct ParamKey {
  const char* key;
  double RobotParams::*robot;
  double MotorParams::*motor;
  double lo, hi;  // accepted range, inclusive (params/params.json)
};

#define ROBOT_KEY(name, def, lo, hi, unit, run_format) {"robot." #name, &RobotParams::name, nullptr, lo, hi},
#define MOTOR_KEY(name, def, lo, hi, unit, run_format) {"motor." #name, nullptr, &MotorParams::name, lo, hi},

const ParamKey kKeys[] = {SLIP_ROBOT_PARAMS(ROBOT_KEY) SLIP_MOTOR_PARAMS(MOTOR_KEY)};
#undef ROBOT_KEY
#undef MOTOR_KEY
const int kKeyCount = sizeof(kKeys) / sizeof(kKeys[0]);

// Splits "effect.param" into an effect id and a parameter index (-2 for "enabled").
bool parse_effect_key(const char* key, int* id, int* k) {
  const char* dot = strrchr(key, '.');
  if (dot == nullptr || dot == key) return false;
  char name[64];
  const size_t len = static_cast<size_t>(dot - key);
  if (len >= sizeof(name)) return false;
  memcpy(name, key, len);
  name[len] = '\0';
  *id = effect_id(name);
  if (*id < 0) return false;
  if (strcmp(dot + 1, "enabled") == 0) {
    *k = -2;
    return true;
  }
  *k = effect_param_index(*id, dot + 1);
  return *k >= 0;
}

// The plant's model settings outside the robot table and the effects' vocabulary.
const char kSpinShareKey[] = "plant.spin_share";

}  // namespace

int param_key_count() { return kKeyCount; }

const char* param_key_name(int i) { return (i >= 0 && i < kKeyCount) ? kKeys[i].key : nullptr; }

int plant_set(Plant& plant, const char* key, double v) {
  if (key == nullptr) return kKeyUnknown;
  for (int i = 0; i < kKeyCount; ++i) {
    const ParamKey& pk = kKeys[i];
    if (strcmp(pk.key, key) != 0) continue;
    if (!isfinite(v) || v < pk.lo || v > pk.hi) return kKeyBadValue;
    if (pk.robot) plant.robot().*pk.robot = v;
    else plant.motor().*pk.motor = v;
    return kKeyOk;
  }
  if (strcmp(key, kSpinShareKey) == 0) return plant.set_spin_share(v) ? kKeyOk : kKeyBadValue;
  int id = -1, k = -1;
  if (!parse_effect_key(key, &id, &k)) return kKeyUnknown;
  if (k == -2) {
    if (!isfinite(v)) return kKeyBadValue;
    plant.effects().enabled[id] = (v != 0.0);
    return kKeyOk;
  }
  if (!effect_param_valid(id, k, v)) return kKeyBadValue;
  plant.effects().p[id][k] = v;
  return kKeyOk;
}

int plant_get(const Plant& plant, const char* key, double* out) {
  if (key == nullptr || out == nullptr) return kKeyUnknown;
  for (int i = 0; i < kKeyCount; ++i) {
    const ParamKey& pk = kKeys[i];
    if (strcmp(pk.key, key) != 0) continue;
    *out = pk.robot ? plant.robot().*pk.robot : plant.motor().*pk.motor;
    return kKeyOk;
  }
  if (strcmp(key, kSpinShareKey) == 0) {
    *out = plant.spin_share();
    return kKeyOk;
  }
  int id = -1, k = -1;
  if (!parse_effect_key(key, &id, &k)) return kKeyUnknown;
  *out = (k == -2) ? (plant.effects().enabled[id] ? 1.0 : 0.0) : plant.effects().p[id][k];
  return kKeyOk;
}

}  // namespace slip
#endif  // !__AVR__
