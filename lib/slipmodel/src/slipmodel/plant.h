// Host-only Euler plant of the slip dynamics with Coulomb stick/slip per wheel.
//
// State: pose of the axle centre o (x, y, phi), body-frame velocity of o (v forward, w lateral,
// +left), yaw rate omega, wheel angles and speeds. Equations, contact model and the time
// stepping are derived in lib/slipmodel/README.md. In short, each step of length dt:
//   1. command pipeline: (delay) -> motor model in duty mode -> gain asymmetry -> (lag);
//   2. normal forces II.27-II.29 (+ II.28 lateral transfer from the previous step's lateral force);
//   3. semi-implicit Euler on the velocities: M (u+ - u)/dt = Q(u) + J^T f, where a stuck wheel's
//      contact force f solves J u+ = 0 (contact point at rest at the end of the step) and is
//      accepted while |f| <= mu_s N; a slipping wheel gets |f| = mu_k N opposite its slip velocity;
//      a slipping wheel whose slip velocity reverses within the step sticks again;
//   4. positions advance with the new velocities.
#ifndef SLIPMODEL_PLANT_H
#define SLIPMODEL_PLANT_H

#if !defined(__AVR__)

#include <deque>

#include <slipmodel/effects.h>
#include <slipmodel/params.h>
#include <slipmodel/traction.h>

namespace slip {

struct PlantState {
  double t_s = 0.0;
  double x_m = 0.0, y_m = 0.0, phi_rad = 0.0;  ///< pose of the axle centre o
  double v_m_s = 0.0;        ///< forward speed of o (body x)
  double w_m_s = 0.0;        ///< lateral speed of o (body y, +left): lateral slip
  double omega_rad_s = 0.0;  ///< yaw rate
  double theta_r_rad = 0.0, theta_l_rad = 0.0;
  double dtheta_r_rad_s = 0.0, dtheta_l_rad_s = 0.0;
  bool slipping_r = false, slipping_l = false;  ///< contact state at the end of the last step
  double tau_r_nm = 0.0, tau_l_nm = 0.0;  ///< motor torque delivered to each wheel, last step
  double N_r = 0.0, N_l = 0.0, N_c = 0.0;  ///< normal forces used in the last step, N
  double F_r_n = 0.0, F_l_n = 0.0;  ///< longitudinal ground force on each wheel (+forward), N
  double L_r_n = 0.0, L_l_n = 0.0;  ///< lateral ground force on each wheel (+left), N
};

class Plant {
 public:
  explicit Plant(const RobotParams& robot = RobotParams(), const MotorParams& motor = MotorParams());

  /// At rest at pose (x, y, phi), t = 0, wheels stuck, wheel angles 0, effect states cleared.
  /// Parameters and effect settings are kept.
  void reset(double x_m, double y_m, double phi_rad);
  /// Sets the velocities (wheels whose contact slip speed is below 1e-9 m/s count as stuck).
  void set_velocity(double v_m_s, double w_m_s, double omega_rad_s, double dtheta_r_rad_s,
                    double dtheta_l_rad_s);
  /// Sets the clock (clears the actuation-delay history if time jumps back by more than 1 µs).
  void set_time(double t_s);

  /// One Euler step with commanded wheel torques (N m).
  void step_torque(double tau_r_nm, double tau_l_nm, double dt_s);
  /// One Euler step with duties in [-1, 1] through the motor model.
  void step_duty(double u_r, double u_l, double dt_s);

  const PlantState& state() const { return s_; }
  /// Motor current of wheel 0 (right) or 1 (left) in the last step, A: the armature current
  /// behind the delivered torque (motor_current_a), with the motor_gain_asymmetry effect taken
  /// as one of torque per ampere (the current is the one the motor model gives, before it).
  double current_a(int wheel) const;

  RobotParams& robot() { return robot_; }
  const RobotParams& robot() const { return robot_; }
  MotorParams& motor() { return motor_; }
  const MotorParams& motor() const { return motor_; }
  Effects& effects() { return fx_; }
  const Effects& effects() const { return fx_; }
  /// Switches one effect and sets its parameters (p1 ignored for one-parameter effects).
  void set_effect(EffectId id, bool on, double p0, double p1 = 0.0);

  /// Share of I_wy whose spin momentum reacts on the body in load_transfer's pitch balance, in
  /// [0, 1] (default 1: the wheel is a rigid body of spin inertia I_wy, the plant's model). A
  /// setting of the model, outside the run-format vocabulary: kept by reset and by clearing the
  /// effects. Returns false (and keeps the old value) outside [0, 1].
  bool set_spin_share(double share);
  double spin_share() const { return spin_share_; }

  /// Kinetic energy of body and wheels, J.
  double kinetic_energy_j() const;
  /// Static normal forces of the plant as configured (II.27-II.29, floor slope, no transfer).
  NormalForces static_normal_forces() const;
  /// II.51 with the plant's effective mu_s and r and its static normal force; wheel 0 right, 1 left.
  double tau_max_nm(int wheel) const;

 private:
  void step(int mode, double in_r, double in_l, double dt_s);

  RobotParams robot_;
  MotorParams motor_;
  Effects fx_;
  PlantState s_;
  bool stuck_[2];
  double slip_dir_[2][2];  // unit breakaway direction of the contact force, per wheel
  double lat_force_prev_n_;
  double ax_prev_m_s2_;
  double spin_acc_prev_rad_s2_;  // theta''_r + theta''_l of the previous step
  double spin_share_ = 1.0;
  double tau_lag_[2];
  struct Cmd { double t_s, r, l; };
  std::deque<Cmd> history_;
};

}  // namespace slip

#endif  // !__AVR__
#endif  // SLIPMODEL_PLANT_H
