// Closed-loop harness: slip::Plant (0.5 ms Euler steps) driven by the control cascade on the
// 25 ms inner / 50 ms outer schedule, with encoder counts quantised as on the robot
// (floor(theta * kEncoderPpr / 2pi), int32). Test code, host only.
#ifndef TEST_CONTROL_CLOSED_LOOP_SIM_H
#define TEST_CONTROL_CLOSED_LOOP_SIM_H

#include <math.h>
#include <stdint.h>

#include <control/cascade.h>
#include <control/reference.h>
#include <slipmodel/plant.h>

namespace sim {

static const double kPlantDt = 5e-4;
static const int kPlantPerInner = 50;  // 25 ms
static const double kPi = 3.14159265358979323846;

struct Result {
  double max_pos_err_m = 0;      ///< max |p_true - p_ref| over the run
  double final_pos_err_m = 0;    ///< at the end
  double e_x = 0, e_y = 0, e_phi = 0;  ///< final tracking errors (true pose, robot frame)
  double max_tail_err_m = 0;     ///< max |p_true - p_ref| over the last quarter of the run
  int slip_steps = 0;            ///< plant steps that ended with a wheel slipping
  double first_slip_t_s = -1;
  double max_tau_cmd_nm = 0;     ///< max |tau requested after the clamp|
  double max_odo_err_m = 0;      ///< max |odometry - truth|
  double final_x_m = 0;          ///< true final x
  double final_x_ref_m = 0;
  int clamp_steps = 0, sat_steps = 0;
  double mean_wheel_accel_0_5 = 0;  ///< true mean wheel acceleration over 0-0.5 s (both wheels)
  double clamped_cmd_nm = 0, clamped_delivered_nm = 0;  ///< sums of slip::tau_max and delivered |torque| over plant steps while clamped
  double utilisation() const { return clamped_cmd_nm > 0 ? clamped_delivered_nm / clamped_cmd_nm : 0; }
};

/// What the controller's command drives: the duty through the datasheet motor (the robot), or
/// its torque after the clamp applied directly (an ideal torque source, as the thesis's
/// Simulink model in II.6).
enum class Actuator { kDuty, kTorque };

inline int32_t counts(double theta_rad) {
  return static_cast<int32_t>(floor(theta_rad * slip::kEncoderPpr / (2.0 * kPi)));
}

/// Adapter interface: the float Controller is used directly; the fixed one through the same
/// calls (see the fixed test).
template <typename Adapter>
Result run(Adapter& ctl, const ctl::ReferenceSpec& ref, double x0, double y0, double phi0, double T_s,
           Actuator act = Actuator::kDuty) {
  slip::Plant plant{slip::RobotParams(), slip::MotorParams()};
  plant.reset(x0, y0, phi0);
  ctl.reset(0, 0, x0, y0, phi0);
  Result res;
  double u_r = 0, u_l = 0;
  const int n_inner = static_cast<int>(lround(T_s / 0.025));
  for (int k = 0; k < n_inner; ++k) {
    const double t = k * 0.025;
    const slip::PlantState& s = plant.state();
    // Firmware order: tick 0 starts the experiment (reset, the outer step with the reference
    // at 0, the first command from rest); in every later 25 ms tick the inner step reads the
    // counts (odometry + velocity loop, using the last velocity command), then, every other
    // tick, the outer step runs on the fresh pose and sets the command for the next inner steps.
    if (k == 0) {
      ctl.start(counts(s.theta_r_rad), counts(s.theta_l_rad), x0, y0, phi0, ref, &u_r, &u_l);
    } else {
      ctl.inner(counts(s.theta_r_rad), counts(s.theta_l_rad), &u_r, &u_l);
      if (k % 2 == 0) ctl.outer(ref, t);
    }
    double ox, oy;
    ctl.odo_xy(&ox, &oy);
    res.max_odo_err_m = fmax(res.max_odo_err_m, hypot(ox - s.x_m, oy - s.y_m));
    res.max_tau_cmd_nm = fmax(res.max_tau_cmd_nm, fmax(fabs(ctl.tau_r()), fabs(ctl.tau_l())));
    res.clamp_steps += ctl.clamped();
    res.sat_steps += ctl.saturated();
    const double tr = ctl.tau_r(), tl = ctl.tau_l();
    const double sr = ctl.slope_r(), sl = ctl.slope_l();
    for (int j = 0; j < kPlantPerInner; ++j) {
      // the firmware advances the duty along its slope every millisecond
      const double ms = floor(j * kPlantDt / 1e-3 + 1e-9);
      if (act == Actuator::kTorque) plant.step_torque(tr, tl, kPlantDt);
      else plant.step_duty(fmin(fmax(u_r + sr * ms, -1.0), 1.0), fmin(fmax(u_l + sl * ms, -1.0), 1.0), kPlantDt);
      if (ctl.clamped()) {  // delivered torque over the physical limit slip::tau_max
        res.clamped_cmd_nm += 0.5 * (ctl.tau_max_phys_r() + ctl.tau_max_phys_l());
        res.clamped_delivered_nm += 0.5 * (fabs(plant.state().tau_r_nm) + fabs(plant.state().tau_l_nm));
      }
      if (plant.state().slipping_r || plant.state().slipping_l) {
        if (res.slip_steps == 0) res.first_slip_t_s = plant.state().t_s;
        ++res.slip_steps;
      }
    }
    const ctl::RefSample rs = ctl::reference_at(ref, static_cast<float>(t + 0.025));
    const double err = hypot(plant.state().x_m - rs.x_m, plant.state().y_m - rs.y_m);
    res.max_pos_err_m = fmax(res.max_pos_err_m, err);
    if (k >= 3 * n_inner / 4) res.max_tail_err_m = fmax(res.max_tail_err_m, err);
    if (k + 1 == 20)  // t = 0.5 s
      res.mean_wheel_accel_0_5 = 0.5 * (plant.state().dtheta_r_rad_s + plant.state().dtheta_l_rad_s) / 0.5;
  }
  const slip::PlantState& s = plant.state();
  const ctl::RefSample rs = ctl::reference_at(ref, static_cast<float>(n_inner * 0.025));
  const double dx = rs.x_m - s.x_m, dy = rs.y_m - s.y_m;
  res.e_x = cos(s.phi_rad) * dx + sin(s.phi_rad) * dy;
  res.e_y = -sin(s.phi_rad) * dx + cos(s.phi_rad) * dy;
  res.e_phi = remainder(rs.phi_rad - s.phi_rad, 2 * kPi);
  res.final_pos_err_m = hypot(dx, dy);
  res.final_x_m = s.x_m;
  res.final_x_ref_m = rs.x_m;
  return res;
}

/// Adapter for the float Controller.
struct FloatAdapter {
  ctl::Controller c;
  explicit FloatAdapter(const ctl::ControlConfig& cfg) : c(cfg) {}
  void reset(int32_t er, int32_t el, double x, double y, double phi) {
    c.reset(er, el, ctl::Pose{static_cast<float>(x), static_cast<float>(y), static_cast<float>(phi)});
  }
  void outer(const ctl::ReferenceSpec& ref, double t) { c.outer_step(ctl::reference_at(ref, static_cast<float>(t))); }
  void start(int32_t er, int32_t el, double x, double y, double phi, const ctl::ReferenceSpec& ref, double* u_r,
             double* u_l) {
    const ctl::InnerOut& o = c.start(er, el, ctl::Pose{static_cast<float>(x), static_cast<float>(y), static_cast<float>(phi)},
                                     ctl::reference_at(ref, 0.0f));
    *u_r = o.pwm_r;
    *u_l = o.pwm_l;
  }
  void inner(int32_t er, int32_t el, double* u_r, double* u_l) {
    const ctl::InnerOut& o = c.inner_step(er, el, 0.025f);
    *u_r = o.pwm_r;
    *u_l = o.pwm_l;
  }
  double tau_r() const { return c.inner().tau_r_nm; }
  double tau_l() const { return c.inner().tau_l_nm; }
  bool clamped() const { return c.inner().clamped_r || c.inner().clamped_l; }
  bool saturated() const { return c.inner().sat_r || c.inner().sat_l; }
  double tau_max_phys_r() const { return c.inner().tau_max_r_nm + (c.config().clamp_enabled ? c.config().margin_nm : 0); }
  double tau_max_phys_l() const { return c.inner().tau_max_l_nm + (c.config().clamp_enabled ? c.config().margin_nm : 0); }
  double slope_r() const { return c.inner().pwm_slope_r; }
  double slope_l() const { return c.inner().pwm_slope_l; }
  void odo_xy(double* x, double* y) const { *x = c.odometry().pose().x_m; *y = c.odometry().pose().y_m; }
};

}  // namespace sim

#endif

#include <control/cascade_q.h>

namespace sim {

/// Adapter for the fixed-point ControllerQ (reference also generated in fixed point).
struct FixedAdapter {
  ctl::ControlConfigQ cfg;
  ctl::ControllerQ c;
  ctl::ReferenceSpecQ spec_q{ctl::ReferenceSpec{ctl::PathKind::kLine, 1.0f, 0.0f, 0.0f}};
  explicit FixedAdapter(const ctl::ControlConfig& f) : cfg(f), c(cfg) {}
  static ctl::PoseQ pose_q(double x, double y, double phi) {
    const double turns = phi / (2 * kPi);
    const uint32_t phi_b32 = static_cast<uint32_t>(static_cast<int64_t>(llround(turns * 4294967296.0)));
    return ctl::PoseQ{static_cast<int32_t>(lround(x * 1048576.0)), static_cast<int32_t>(lround(y * 1048576.0)), phi_b32};
  }
  void reset(int32_t er, int32_t el, double x, double y, double phi) { c.reset(er, el, pose_q(x, y, phi)); }
  void start(int32_t er, int32_t el, double x, double y, double phi, const ctl::ReferenceSpec& ref, double* u_r,
             double* u_l) {
    spec_q = ctl::ReferenceSpecQ(ref);
    const ctl::InnerOutQ& o = c.start(er, el, pose_q(x, y, phi), ctl::reference_at_q(spec_q, 0));
    *u_r = o.pwm_r_q15 / 32768.0;
    *u_l = o.pwm_l_q15 / 32768.0;
  }
  void outer(const ctl::ReferenceSpec& ref, double t) {
    spec_q = ctl::ReferenceSpecQ(ref);
    c.outer_step(ctl::reference_at_q(spec_q, static_cast<uint32_t>(lround(t * 1000.0))));
  }
  void inner(int32_t er, int32_t el, double* u_r, double* u_l) {
    const ctl::InnerOutQ& o = c.inner_step(er, el, 25000);
    *u_r = o.pwm_r_q15 / 32768.0;
    *u_l = o.pwm_l_q15 / 32768.0;
  }
  double tau_r() const { return c.inner().tau_r_q16 / 65536.0; }
  double tau_l() const { return c.inner().tau_l_q16 / 65536.0; }
  bool clamped() const { return c.inner().clamped_r || c.inner().clamped_l; }
  bool saturated() const { return c.inner().sat_r || c.inner().sat_l; }
  double tau_max_phys_r() const { return (c.inner().tau_max_r_q16 + cfg.margin_q16) / 65536.0; }
  double tau_max_phys_l() const { return (c.inner().tau_max_l_q16 + cfg.margin_q16) / 65536.0; }
  double slope_r() const { return c.inner().slope_r_q15 / 32768.0; }
  double slope_l() const { return c.inner().slope_l_q15 / 32768.0; }
  void odo_xy(double* x, double* y) const {
    *x = c.odometry().pose().x_q20 / 1048576.0;
    *y = c.odometry().pose().y_q20 / 1048576.0;
  }
};

}  // namespace sim
