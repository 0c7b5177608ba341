// The optional "left-out physics" effects of shared/spec/run-format.md, with exactly its
// names and parameter names. Host only. Every effect is off by default; each parameter's
// default is the neutral value (the effect switched on with its defaults changes nothing),
// except load_transfer.h whose default is Table II.2's h. Equations: lib/slipmodel/README.md.
#ifndef SLIPMODEL_EFFECTS_H
#define SLIPMODEL_EFFECTS_H

#if !defined(__AVR__)

namespace slip {

enum EffectId {
  kFrictionCoefficient = 0,  // mu_s, mu_k
  kWheelRadius,              // r_eff
  kTrackWidth,               // b_eff
  kMotorBackEmf,             // ke_ratio
  kDriverVoltageDrop,        // volts
  kActuationDelay,           // delay_s
  kMotorLag,                 // tau_s
  kAxleViscous,              // c
  kAxleCoulomb,              // torque
  kCasterDrag,               // mu
  kLoadTransfer,             // h
  kStribeck,                 // mu_k0, v_s
  kDeadband,                 // volts
  kMotorGainAsymmetry,       // ratio
  kFloorSlope,               // rad
  kEffectCount
};

static const int kMaxEffectParams = 2;

struct EffectInfo {
  const char* name;
  int param_count;
  const char* param_names[kMaxEffectParams];
  double defaults[kMaxEffectParams];
};

/// The vocabulary, indexed by EffectId.
const EffectInfo& effect_info(int id);
/// Effect id for a name, or -1.
int effect_id(const char* name);
/// Parameter index within an effect, or -1.
int effect_param_index(int id, const char* param);
/// True if v is a usable value for parameter k of effect id (finite and in its physical range:
/// lengths, ratios and v_s > 0; times, coefficients, torques, deadband >= 0; |rad| < pi/2).
bool effect_param_valid(int id, int k, double v);

/// Switches and parameters of all effects (plain data, copyable).
struct Effects {
  bool enabled[kEffectCount];
  double p[kEffectCount][kMaxEffectParams];
  Effects();
  bool on(EffectId id) const { return enabled[id]; }
  /// Parameter k of effect id if the effect is on, else its neutral default.
  double get(EffectId id, int k) const;
  void clear();  ///< all off, all parameters back to defaults
};

}  // namespace slip

#endif  // !__AVR__
#endif  // SLIPMODEL_EFFECTS_H
