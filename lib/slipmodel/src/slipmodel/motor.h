// The DC motor and H-bridge model the firmware assumes (datasheet figures, per wheel).
//
//   tau = k_t (u V - k_e theta_dot) / R
// With k_t/R = stall_nm / supply_v and k_e = supply_v / no_load_rad_s this is
//   tau = stall_nm * (u - theta_dot / no_load_rad_s).
//
// Saturation, exactly:
//   1. u is clamped to [-1, 1]; a NaN u is treated as 0 (coast at zero volts).
//   2. the resulting torque is clamped to [-stall_nm, +stall_nm] (the driver cannot deliver more
//      than the stall current, e.g. when the wheel is back-driven against the command).
// Usable on the AVR (double is float there); no heap, no state.
#ifndef SLIPMODEL_MOTOR_H
#define SLIPMODEL_MOTOR_H

#include <slipmodel/params.h>

namespace slip {

/// Motor-side imperfections (the effects motor_back_emf, driver_voltage_drop, deadband).
/// The defaults are neutral (the datasheet model).
struct MotorImperfections {
  double ke_ratio = 1.0;    ///< true back-EMF constant / datasheet one
  double drop_v = 0.0;      ///< volts lost in the H-bridge and battery: V_eff = supply_v - drop_v
  double deadband_v = 0.0;  ///< |drive voltage| below this gives none; above it, it is reduced by it
};

/// Datasheet model: torque (N m) for duty u at wheel speed dtheta_rad_s.
double motor_torque_nm(const MotorParams& m, double u, double dtheta_rad_s);

/// The same model with imperfections:
///   V = clamp(u,-1,1) (supply_v - drop_v);  V' = sign(V) max(|V| - deadband_v, 0)
///   tau = clamp(stall_nm (V' / supply_v - ke_ratio dtheta / no_load_rad_s), -stall_nm, stall_nm)
double motor_torque_nm(const MotorParams& m, double u, double dtheta_rad_s,
                       const MotorImperfections& x);

/// Inverse of the datasheet model: the duty that gives tau_nm at dtheta_rad_s,
/// u = tau_nm / stall_nm + dtheta_rad_s / no_load_rad_s, clamped to [-1, 1] (NaN gives 0).
/// Exact inverse wherever the result is inside (-1, 1) and |tau_nm| <= stall_nm.
double motor_duty_for_torque(const MotorParams& m, double tau_nm, double dtheta_rad_s);

/// The motor an imperfect one amounts to in the datasheet model (deadband left out): with
/// S = supply_v, D = drop_v, k = ke_ratio the torque is stall (S - D)/S u - k stall dtheta/no_load,
/// the datasheet form with stall' = stall (S - D)/S and no_load' = no_load (S - D)/(S k)
/// (supply_v and stall_a unchanged). So motor_duty_for_torque with it inverts
/// motor_torque_nm(m, u, dtheta, x) inside the clamps: the firmware's torque->duty map with a
/// fitted back-EMF ratio and voltage drop (SetModel). Needs k > 0 and D < S (else m unchanged).
MotorParams motor_as_driven(const MotorParams& m, const MotorImperfections& x);

/// Motor current (A) that delivers the wheel torque tau_nm: a DC motor's torque is k_t i, and the
/// datasheet's stall point gives k_t = stall_nm / stall_a (per wheel, gearbox included). Signed;
/// the Motor Shield R3's sense output reports its magnitude. Friction on the axle acts after the
/// motor, so it changes the current only through the speed it costs.
double motor_current_a(const MotorParams& m, double tau_nm);

}  // namespace slip

#endif  // SLIPMODEL_MOTOR_H
