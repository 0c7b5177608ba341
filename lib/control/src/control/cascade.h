// The control cascade (float): kinematic tracking controller (outer loop, II.40-II.45),
// velocity/torque controller with anti-windup (inner loop, II.46-II.48), torque split (II.49
// re-derived), per-wheel tau_max clamp (II.51) and torque->PWM map with back-EMF compensation.
//
// Derivations (details and sign checks in lib/control/README.md):
//
// * Tracking error (II.40 corrected). With the error expressed in the ROBOT frame,
//     e_x =  cos(phi) (x_r - x) + sin(phi) (y_r - y)
//     e_y = -sin(phi) (x_r - x) + cos(phi) (y_r - y)
//     e_phi = wrap(phi_r - phi)
//   the error dynamics are exactly II.41 (v_d, omega_d being the robot's v, omega):
//     de_x = omega e_y - v + v_r cos e_phi,  de_y = -omega e_x + v_r sin e_phi,
//     de_phi = omega_r - omega.
//   (II.40 as printed rotates q - q_r by phi_r, which does not give II.41.)
//   V = (e_x^2 + e_y^2)/2 + (1 - cos e_phi)/k_y and II.44
//     v_d = v_r cos e_phi + k_x e_x,  omega_d = omega_r + v_r k_y e_y + k_phi sin e_phi
//   give dV/dt = -k_x e_x^2 - (k_phi/k_y) sin^2 e_phi  (II.45 with the square restored).
//
// * Velocity loop. From lib/slipmodel's pure-rolling model (rolling.h), which includes the
//   wheels' spin inertia and the offset d of the centre of mass:
//     m_eff dv/dt = F + m_t d omega^2,          F = (tau_r + tau_l) / r      [N]
//     I_eff domega/dt = M - m_t d omega v,      M = b (tau_r - tau_l) / r    [N m]
//   II.47 with these masses, plus an integral term (anti-windup: conditional integration):
//     F = m_eff dv_ff - m_t d omega^2 + k_l e_v + I_v,   dI_v = k_il e_v dt
//     M = I_eff dw_ff + m_t d omega v + k_a e_w + I_w,   dI_w = k_ia e_w dt
//   where dv_ff, dw_ff are the reference accelerations (the derivative of the kinematic
//   correction is left out: in discrete time it is noise).
//   The thesis variant (Variant::kThesis) is II.47 as printed: m_t and I_t in place of m_eff
//   and I_eff, no m_t d terms, and (thesis_gains()) no integral.
// * Split (II.49 re-derived for the conventions above; II.12/II.49 have the sign of the yaw
//   term reversed and a factor 2 wrong):
//     tau_r = (r/2) (F + M/b),  tau_l = (r/2) (F - M/b)
// * Clamp (II.51): |tau_i| <= tau_max(N_i), N_i from slip::normal_forces with the lateral force
//   m_t (v omega + d domega) that the wheels must supply in a turn (II.28 load transfer).
// * PWM: u_i = slip::motor_duty_for_torque(motor, tau_i, dtheta_i) = tau/stall + dtheta/no_load,
//   saturated to [-1, 1]. A clamped wheel gets all of its limit: its back-EMF term follows the
//   wheel speed over the coming tick. The measured speed (the mean over the last tick, i.e. the
//   speed half a tick ago) advanced over half a tick by the last tick's model acceleration gives
//   the speed at the tick's start, and the duty then ramps with the model acceleration of the
//   clamped torque, alpha = tau / (m_eff r^2 / 2) (slipmodel's rolling model, straight line;
//   pwm_slope_*: duty per millisecond, applied by the firmware every millisecond). The clamp
//   limit is tau_max less a margin, the back-EMF torque of kBackEmfMarginCounts encoder counts
//   per tick: the speed measurement's error (below one count) must not push the delivered
//   torque above tau_max. In a turn the straight-line model misses (a_Q - a_P) Q of the
//   acceleration (a_P = 2/(r^2 m_eff), a_Q = 2 b^2/(r^2 I_eff): 444 and 452 rad/s^2 per N m
//   with Table II.2), inside the margin. lib/control/README.md has the figures.
#ifndef CONTROL_CASCADE_H
#define CONTROL_CASCADE_H

#include <stdint.h>

#include <control/odometry.h>
#include <control/reference.h>
#include <slipmodel/params.h>

namespace ctl {

/// Margin of the back-EMF term of a clamped wheel, in encoder counts per inner tick.
constexpr float kBackEmfMarginCounts = 1.25f;

/// Controller gains (SI units).
struct Gains {
  float k_x;    ///< 1/s        outer: v_d += k_x e_x
  float k_y;    ///< 1/m^2      outer: omega_d += v_r k_y e_y
  float k_phi;  ///< 1/s        outer: omega_d += k_phi sin e_phi
  float k_l;    ///< N s/m      inner: F += k_l e_v
  float k_a;    ///< N m s      inner: M += k_a e_omega
  float k_il;   ///< N/m        inner: integral of e_v
  float k_ia;   ///< N m        inner: integral of e_omega
};

/// Which velocity loop the cascade runs (the kinematic law, split, clamp, PWM and odometry are
/// the same for both).
///  * kImproved: this project's loop, feed-forward with slipmodel's rolling masses m_eff, I_eff
///    (wheel spin inertia included) and the m_t d coupling terms, plus an integral term.
///  * kThesis: II.47 as printed, feed-forward with m_t and I_t alone, P gains, no coupling
///    terms; with thesis_gains() no integral term.
enum class Variant : uint8_t { kImproved = 0, kThesis = 1 };
static const uint8_t kVariantCount = 2;

/// Default gains: velocity loop about 6 rad/s (k_l/m_eff, k_a/I_eff), well inside the 25 ms
/// sample rate; outer loop 2-3 rad/s; e_y loop damping about 0.8 at v_r = 0.8 m/s.
Gains default_gains();

/// Gains of the thesis's controller (II.44, II.47). The thesis states none; k_x = 2 1/s and
/// k_l = 6 N s/m are the gains of a grid (k_x 1..3, k_l 3..8) with which II.6.2 (torque
/// source, clamp off) shows the thesis's slip pattern and whose peak torques deviate least from
/// the captions' 0.09 / 0.1 / 0.13 N m (criterion and sensitivity in lib/control/README.md and
/// the demo's table); k_a = k_l I_t / m_t (the same 3.7 rad/s bandwidth for omega); k_y, k_phi
/// as default_gains(); no integral (k_il = k_ia = 0).
Gains thesis_gains();

/// The gains a variant uses by default.
Gains gains_for(Variant v);

/// Constant configuration of the cascade (float path).
struct ControlConfig {
  slip::RobotParams robot;
  slip::MotorParams motor;
  Gains gains;
  int32_t counts_per_rev;
  Variant variant;
  float m_ff_kg;         ///< feed-forward mass: slip::rolling_mass_kg (improved), m_t (thesis)
  float I_ff_kgm2;       ///< feed-forward yaw inertia: slip::rolling_yaw_inertia_kgm2 (improved), I_t (thesis)
  float mtd_ff_kg_m;     ///< m_t d in the coupling terms (improved), 0 (thesis)
  float v_max_m_s;       ///< |v_d| limit (r * no-load speed)
  float omega_max_rad_s; ///< |omega_d| limit
  float integ_max_n;     ///< |I_v| limit, N
  float integ_max_nm;    ///< |I_w| limit, N m
  bool clamp_enabled;    ///< tau_max clamp on/off (II.6.3 compares both)
  float wheel_accel_per_nm;  ///< 2/(r^2 m_eff): a wheel's rolling acceleration per N m (straight line)
  float count_rad;       ///< one encoder count, 2 pi / ppr
  float margin_nm;       ///< the clamp's margin below tau_max (back-EMF torque of kBackEmfMarginCounts per 25 ms)
};

/// Builds the configuration from the physics library (one source of truth).
ControlConfig make_control_config(const slip::RobotParams& robot, const slip::MotorParams& motor,
                                  const Gains& gains, bool clamp_enabled = true,
                                  Variant variant = Variant::kImproved);

/// Outer-loop result.
struct KinematicOut {
  float e_x_m, e_y_m, e_phi_rad;
  float v_d_m_s, omega_d_rad_s;
};

/// II.40-II.44 (corrected frame), with |v_d|, |omega_d| saturated to the given limits.
KinematicOut kinematic_law(const Gains& g, const Pose& pose, const RefSample& ref, float v_max_m_s,
                           float omega_max_rad_s);

struct WheelPair {
  float r;
  float l;
};

/// Torque split: tau_r = (r/2)(F + M/b), tau_l = (r/2)(F - M/b).
WheelPair split_torque(float wheel_radius_m, float half_track_m, float force_n, float moment_nm);

/// Symmetric clamp |tau| <= tau_max; sets *clamped when it acted.
float clamp_torque(float tau_nm, float tau_max_nm, bool* clamped);

/// Torque -> duty through the datasheet motor, with back-EMF compensation, saturated to
/// [-1, 1]; *saturated set when the duty hit the limit.
float torque_to_pwm(const slip::MotorParams& m, float tau_nm, float dtheta_rad_s, bool* saturated);

/// Inner-loop output (what the firmware applies and reports).
struct InnerOut {
  float pwm_r, pwm_l;            ///< duty in [-1, 1]
  float tau_r_nm, tau_l_nm;      ///< requested wheel torque after the clamp
  float tau_max_r_nm, tau_max_l_nm;  ///< the clamp's limit: slip::tau_max less the back-EMF margin
  bool clamped_r, clamped_l;     ///< the clamp acted
  bool sat_r, sat_l;             ///< the duty saturated
  OdoStatus odo;
  float pwm_slope_r, pwm_slope_l;  ///< duty per millisecond over the coming tick (clamped wheels; 0 otherwise)
};

/// The whole cascade with its state (float path). No heap; 250 bytes on the AVR.
class Controller {
 public:
  explicit Controller(const ControlConfig& cfg);
  /// Start at pose p with encoder readings enc_r, enc_l; clears integrators and commands.
  void reset(int32_t enc_r, int32_t enc_l, const Pose& p);
  /// Start of an experiment, at its first inner tick (reference time 0): reset(enc_r, enc_l, p),
  /// the outer step with ref0 (the reference at t = 0), and the first command at once, from
  /// rest (wheel speeds 0; nothing integrated). The inner steps follow one period apart, the
  /// outer step after every second one (the schedule of the firmware and lib/closedloop).
  const InnerOut& start(int32_t enc_r, int32_t enc_l, const Pose& p, const RefSample& ref0);
  /// Outer loop (50 ms): tracking law on the current odometry pose; also refreshes the
  /// per-wheel tau_max. Call it after the inner step of the same tick (fresh pose).
  const KinematicOut& outer_step(const RefSample& ref);
  /// Inner loop (25 ms): odometry from the counts, velocity loop, split, clamp, PWM.
  const InnerOut& inner_step(int32_t enc_r, int32_t enc_l, float dt_s);

  const Odometry& odometry() const { return odo_; }
  const KinematicOut& kinematic() const { return kin_; }
  const InnerOut& inner() const { return out_; }
  float integ_v_n() const { return i_v_; }
  float integ_w_nm() const { return i_w_; }
  ControlConfig& config() { return cfg_; }
  const ControlConfig& config() const { return cfg_; }

 private:
  void update_tau_max();
  /// The velocity loop, split, clamp and PWM on the current odometry; integrates over dt_s
  /// (0: nothing).
  const InnerOut& command(float dt_s);

  ControlConfig cfg_;
  OdometryConfig odo_cfg_;
  Odometry odo_;
  KinematicOut kin_;
  InnerOut out_;
  float dv_ff_, dw_ff_;
  float i_v_, i_w_;
  int8_t was_r_, was_l_;  // the sign a wheel was clamped with in the last tick (+1, -1, 0)
};

}  // namespace ctl

#endif  // CONTROL_CASCADE_H
