// Robot, motor and encoder parameters (Table II.2 of the thesis and the datasheet motor).
//
// Units are SI. `b` is HALF the wheel separation (the thesis writes the separation as 2b).
// Members are `double`: on the host that is IEEE binary64; avr-gcc 5.4 makes `double` a 32-bit
// float, so on the AVR these are plain floats and cost nothing extra.
#ifndef SLIPMODEL_PARAMS_H
#define SLIPMODEL_PARAMS_H

#include <stdint.h>

namespace slip {

/// Mechanical parameters, named as in Table II.2.
struct RobotParams {
  double mu_s = 0.241;      ///< static wheel-ground friction coefficient
  double mu_k = 0.239;      ///< kinetic wheel-ground friction coefficient
  double b = 0.105;         ///< half the wheel separation, m
  double e = 0.095;         ///< centre of mass to caster contact (longitudinal), m
  double d = 0.055;         ///< axle centre o to centre of mass c (longitudinal), m
  double g = 9.81;          ///< gravity, m/s^2
  double h = 0.0216;        ///< centre-of-mass height above the ground, m
  double m_r = 1.5;         ///< platform mass (without the two driven wheels), kg
  double I_rz = 0.009753;   ///< platform yaw inertia about c, kg m^2
  double I_wz = 0.000584;   ///< one wheel's inertia about the vertical axis, kg m^2
  double I_wy = 0.001168;   ///< one wheel's (plus rotor's) inertia about its axle, kg m^2
  double r = 0.0365;        ///< wheel radius, m
  double m_w = 0.064;       ///< one wheel's mass, kg

  /// Total mass m_t = m_r + 2 m_w (lumped at c, as II.27-II.29 assume).
  constexpr double m_t() const { return m_r + 2.0 * m_w; }
  /// Yaw inertia of the whole robot about the vertical axis through c, wheel spin excluded:
  /// I_t = I_rz + 2 (I_wz + m_w b^2). The wheels' small longitudinal offset d from c is
  /// neglected (2 m_w d^2 = 3.9e-4 kg m^2, 3 % of I_t), the same lumping as II.29.
  constexpr double I_t() const { return I_rz + 2.0 * (I_wz + m_w * b * b); }
  /// Yaw inertia about the axle centre o: I_o = I_t + m_t d^2 (parallel axes).
  constexpr double I_o() const { return I_t() + m_t() * d * d; }
};

/// Datasheet DC motor and driver, per wheel (the wheel is on the motor shaft).
struct MotorParams {
  double supply_v = 12.0;        ///< H-bridge supply voltage, V
  double no_load_rad_s = 36.65;  ///< no-load speed at supply_v, rad/s
  double stall_nm = 0.77;        ///< stall torque at supply_v, N m
  double stall_a = 2.0;          ///< stall current at supply_v, A (thesis III.1: "2 A maximum current")
};

/// Encoder counts per wheel revolution (III.1).
static const int32_t kEncoderPpr = 1856;

/// Table II.2 defaults (the default-constructed RobotParams).
constexpr RobotParams table_ii2() { return RobotParams{}; }
/// Datasheet motor defaults.
constexpr MotorParams datasheet_motor() { return MotorParams{}; }

}  // namespace slip

#endif  // SLIPMODEL_PARAMS_H
