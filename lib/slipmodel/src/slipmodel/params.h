// Robot, motor and encoder parameters (Table II.2 of the thesis and the datasheet motor).
//
// Units are SI. `b` is HALF the wheel separation (the thesis writes the separation as 2b).
// Members are `double`: on the host that is IEEE binary64; avr-gcc 5.4 makes `double` a 32-bit
// float, so on the AVR these are plain floats and cost nothing extra.
#ifndef SLIPMODEL_PARAMS_H
#define SLIPMODEL_PARAMS_H

#include <stdint.h>

#include <slipmodel/params_table.h>  // the values, units, ranges: generated from params/params.json

namespace slip {

/// Mechanical parameters, named as in Table II.2. Defaults, units and accepted ranges:
/// params/params.json (slip::table::*, SLIP_ROBOT_PARAMS in the generated params_table.h).
struct RobotParams {
  double mu_s = table::mu_s;  ///< static wheel-ground friction coefficient
  double mu_k = table::mu_k;  ///< kinetic wheel-ground friction coefficient
  double b = table::b;        ///< half the wheel separation, m
  double e = table::e;        ///< centre of mass to caster contact (longitudinal), m
  double d = table::d;        ///< axle centre o to centre of mass c (longitudinal), m
  double g = table::g;        ///< gravity, m/s^2
  double h = table::h;        ///< centre-of-mass height above the ground, m
  double m_r = table::m_r;    ///< platform mass (without the two driven wheels), kg
  double I_rz = table::I_rz;  ///< platform yaw inertia about c, kg m^2
  double I_wz = table::I_wz;  ///< one wheel's inertia about the vertical axis, kg m^2
  double I_wy = table::I_wy;  ///< one wheel's (plus rotor's) inertia about its axle, kg m^2
  double r = table::r;        ///< wheel radius, m
  double m_w = table::m_w;    ///< one wheel's mass, kg

  /// Total mass m_t = m_r + 2 m_w (lumped at c, as II.27-II.29 assume).
  constexpr double m_t() const { return m_r + 2.0 * m_w; }
  /// Yaw inertia of the whole robot about the vertical axis through c, wheel spin excluded:
  /// I_t = I_rz + 2 (I_wz + m_w b^2). The wheels' small longitudinal offset d from c is
  /// neglected (2 m_w d^2 = 3.9e-4 kg m^2, 3 % of I_t), the same lumping as II.29.
  constexpr double I_t() const { return I_rz + 2.0 * (I_wz + m_w * b * b); }
  /// Yaw inertia about the axle centre o: I_o = I_t + m_t d^2 (parallel axes).
  constexpr double I_o() const { return I_t() + m_t() * d * d; }
};

/// Datasheet DC motor and driver, per wheel (the wheel is on the motor shaft); thesis III.1.
struct MotorParams {
  double supply_v = table::supply_v;            ///< H-bridge supply voltage, V
  double no_load_rad_s = table::no_load_rad_s;  ///< no-load speed at supply_v, rad/s
  double stall_nm = table::stall_nm;            ///< stall torque at supply_v, N m
  double stall_a = table::stall_a;              ///< stall current at supply_v, A
};

/// Encoder counts per wheel revolution (III.1). The firmware's ENC_COUNTS_PER_REV (board.h) is
/// the same generated constant.
static const int32_t kEncoderPpr = SLIP_ENCODER_COUNTS_PER_REV;

/// Table II.2 defaults (the default-constructed RobotParams).
constexpr RobotParams table_ii2() { return RobotParams{}; }
/// Datasheet motor defaults.
constexpr MotorParams datasheet_motor() { return MotorParams{}; }

}  // namespace slip

#endif  // SLIPMODEL_PARAMS_H
