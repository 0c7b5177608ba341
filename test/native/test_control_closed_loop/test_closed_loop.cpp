// The float cascade in closed loop with slip::Plant: convergence (Lyapunov, II.42-II.45) on a
// line, an arc and a figure eight; the thesis's II.6.2 and II.6.3 experiments.
#include <math.h>
#include <stdio.h>

#include <unity.h>

#include "closed_loop_sim.h"
#include "../table.h"
#include <slipmodel/rolling.h>
#include <slipmodel/traction.h>

using namespace ctl;

namespace {

ControlConfig config(bool clamp) {
  return make_control_config(slip::RobotParams(), slip::MotorParams(), default_gains(), clamp);
}

sim::Result run_float(const ReferenceSpec& ref, bool clamp, double x0, double y0, double phi0, double T) {
  sim::FloatAdapter ad(config(clamp));
  return sim::run(ad, ref, x0, y0, phi0, T);
}

// The largest wheel acceleration without slip in a straight line (pure rolling at tau_max):
// tau_max = (m_eff r^2 / 2) alpha*  (slipmodel's rolling mass includes the wheel inertia).
double alpha_star() {
  const slip::RobotParams p;
  const double tau = slip::tau_max(p, slip::normal_forces(p).N_r);
  return tau / (slip::rolling_mass_kg(p) * p.r * p.r / 2.0);
}

void check_converged(const sim::Result& r, double pos_tol, double phi_tol, const char* what) {
  char m[200];
  snprintf(m, sizeof m, "%s: e_x %.4g e_y %.4g e_phi %.4g (tol %.3g m, %.3g rad); start error %.3g m",
           what, r.e_x, r.e_y, r.e_phi, pos_tol, phi_tol, r.max_pos_err_m);
  printf("%s\n", m);
  TEST_ASSERT_TRUE_MESSAGE(fabs(r.e_x) < pos_tol && fabs(r.e_y) < pos_tol && fabs(r.e_phi) < phi_tol, m);
}

}  // namespace

void setUp() {}
void tearDown() {}

// Offset start: 10 cm behind, 15 cm to the left, 0.4 rad off heading.
void test_line_converges_from_offset() {
  const sim::Result r = run_float(ReferenceSpec{PathKind::kLine, 0.5f, 0.5f, 0.0f}, true, -0.1, 0.15, 0.4, 20.0);
  TEST_ASSERT_TRUE(r.max_pos_err_m > 0.15);  // it really started off the reference
  check_converged(r, 2e-3, 5e-3, "line");
}

void test_arc_converges_from_offset() {
  const sim::Result r = run_float(ReferenceSpec{PathKind::kArc, 0.5f, 0.4f, 0.6f}, true, -0.1, 0.15, 0.4, 20.0);
  check_converged(r, 2e-3, 5e-3, "arc R = 0.6 m");
  // Right-hand arc too (negative radius).
  const sim::Result r2 = run_float(ReferenceSpec{PathKind::kArc, 0.5f, 0.4f, -0.6f}, true, 0.1, -0.1, -0.3, 20.0);
  check_converged(r2, 2e-3, 5e-3, "arc R = -0.6 m");
}

void test_figure_eight_converges_from_offset() {
  // The eight is curvature-continuous (kappa = cos(tau)/R), so the errors decay as on the line
  // and the arc; what remains is a band from the 50 ms outer step holding v_d, omega_d while
  // omega_r changes (it halves with the outer step every 25 ms; 0 on the line and the arc, whose
  // omega_r is constant). 48 s = 2.1 laps (L = 15.1 R = 9.07 m); the last quarter (36-48 s)
  // contains a crossing and both lobe ends. Tolerance: the line's and arc's (2 mm, 5 mrad) on
  // the final errors and on the whole last quarter (measured band 1.7 mm / 1.6 mm; the old
  // eight of two circles: 2.7 cm, as its curvature jumps by 2/R at each crossing).
  const float radii[] = {0.6f, -0.6f};
  for (float R : radii) {
    const sim::Result r =
        run_float(ReferenceSpec{PathKind::kFigureEight, 0.5f, 0.4f, R}, true, -0.1, 0.15, 0.4, 48.0);
    char what[80];
    snprintf(what, sizeof what, "figure eight R = %.1f m (last-quarter band %.4f m)", R, r.max_tail_err_m);
    TEST_ASSERT_TRUE(r.max_pos_err_m > 0.15);  // it really started off the reference
    check_converged(r, 2e-3, 5e-3, what);
    TEST_ASSERT_TRUE_MESSAGE(r.max_tail_err_m < 2e-3, what);
    TEST_ASSERT_EQUAL_INT(0, r.sat_steps);
  }
}

// II.6.2, clamp off. This model's no-slip limit is alpha* = 41.0 rad/s^2 (tau_max = 0.0924 N m
// over the rolling inertia m_eff r^2/2 = 2.25e-3 kg m^2), below the thesis's 44 rad/s^2.
void test_ii62_clamp_off_slip_threshold() {
  const double a_star = alpha_star();
  printf("II.6.2: no-slip wheel-acceleration limit alpha* = %.2f rad/s^2\n", a_star);
  TEST_ASSERT_TRUE(a_star > 40.0 && a_star < 42.0);
  const float below = static_cast<float>(0.75 * a_star);
  const sim::Result r0 = run_float(straight_profile(tbl::kWheelR_m, below), false, 0, 0, 0, 3.0);
  printf("II.6.2: %.1f rad/s^2: slip steps %d, max tau %.4f N m\n", below, r0.slip_steps, r0.max_tau_cmd_nm);
  TEST_ASSERT_EQUAL_INT(0, r0.slip_steps);
  const float accels[] = {44.0f, 48.0f, 72.0f};
  double prev_loss = 0.0;
  for (float a : accels) {
    const sim::Result r = run_float(straight_profile(tbl::kWheelR_m, a), false, 0, 0, 0, 3.0);
    printf("II.6.2: %.0f rad/s^2: slip steps %d (first at %.3f s), max tau %.4f N m, "
           "position lost to slip (odometry - truth) %.4f m\n",
           a, r.slip_steps, r.first_slip_t_s, r.max_tau_cmd_nm, r.max_odo_err_m);
    TEST_ASSERT_TRUE(r.slip_steps > 0);
    TEST_ASSERT_TRUE(r.max_odo_err_m > prev_loss);  // more slip at a higher acceleration
    prev_loss = r.max_odo_err_m;
  }
}

// II.6.2 with the thesis's controller (II.47 as printed: feed-forward m_t alone, P gains, no
// integral; thesis_gains()), an ideal torque source and the clamp off, as the thesis simulated
// it: no slip at 44, slip at 48 and 72 rad/s^2, and the peak commanded torques within 0.01 N m
// of the captions (0.09, 0.1, 0.13 N m). The controller lags the profile: the wheels do not
// accelerate at 44 rad/s^2 (rolling at 44 would need 0.0991 N m > tau_max).
void test_ii62_thesis_controller() {
  const float accels[] = {44.0f, 48.0f, 72.0f};
  const double caption[] = {0.09, 0.1, 0.13};
  const bool slips[] = {false, true, true};
  for (int i = 0; i < 3; ++i) {
    sim::FloatAdapter ad(make_control_config(slip::RobotParams(), slip::MotorParams(), thesis_gains(), false,
                                             Variant::kThesis));
    const sim::Result r = sim::run(ad, straight_profile(tbl::kWheelR_m, accels[i]), 0, 0, 0, 3.0, sim::Actuator::kTorque);
    char m[200];
    snprintf(m, sizeof m, "II.6.2 thesis controller %.0f rad/s^2: slip steps %d, peak tau %.4f N m (caption %.2f), "
             "mean wheel acceleration 0-0.5 s %.1f rad/s^2, lost to slip %.4f m",
             accels[i], r.slip_steps, r.max_tau_cmd_nm, caption[i], r.mean_wheel_accel_0_5, r.max_odo_err_m);
    printf("%s\n", m);
    TEST_ASSERT_TRUE_MESSAGE((r.slip_steps > 0) == slips[i], m);
    TEST_ASSERT_TRUE_MESSAGE(fabs(r.max_tau_cmd_nm - caption[i]) <= 0.01, m);
    TEST_ASSERT_TRUE_MESSAGE(r.mean_wheel_accel_0_5 < accels[i], m);  // it lags the profile
  }
  // The improved controller follows the profile (its feed-forward includes the wheels' spin
  // inertia), so it slips at all three.
  for (int i = 0; i < 3; ++i) {
    sim::FloatAdapter ad(config(false));
    const sim::Result r = sim::run(ad, straight_profile(tbl::kWheelR_m, accels[i]), 0, 0, 0, 3.0, sim::Actuator::kTorque);
    printf("II.6.2 improved controller %.0f rad/s^2, torque source: slip steps %d, peak tau %.4f N m, "
           "mean wheel acceleration %.1f rad/s^2\n", accels[i], r.slip_steps, r.max_tau_cmd_nm, r.mean_wheel_accel_0_5);
    TEST_ASSERT_TRUE(r.slip_steps > 0);
  }
}

// II.6.3 at 72 rad/s^2, with and without the clamp.
void test_ii63_clamp_prevents_slip_at_72() {
  const ReferenceSpec ref = straight_profile(tbl::kWheelR_m, 72.0f);
  const sim::Result off = run_float(ref, false, 0, 0, 0, 20.0);
  const sim::Result on = run_float(ref, true, 0, 0, 0, 20.0);
  const sim::Result off3 = run_float(ref, false, 0, 0, 0, 3.0);
  const sim::Result on3 = run_float(ref, true, 0, 0, 0, 3.0);
  printf("II.6.3 72 rad/s^2 (thesis: max error 0.30 m without, 0.16 m with the clamp)\n");
  printf("  clamp off: slip steps %5d, max |p - p_ref| %.3f m, at 3 s %.3f m, at 20 s %.3f m, odometry drift %.3f m\n",
         off.slip_steps, off.max_pos_err_m, off3.final_pos_err_m, off.final_pos_err_m, off.max_odo_err_m);
  printf("  clamp on : slip steps %5d, max |p - p_ref| %.3f m, at 3 s %.3f m, at 20 s %.3f m, odometry drift %.3f m, "
         "delivered / tau_max while clamped %.3f\n",
         on.slip_steps, on.max_pos_err_m, on3.final_pos_err_m, on.final_pos_err_m, on.max_odo_err_m, on.utilisation());
  // The clamped wheels get their limit (tau_max less the back-EMF margin), within 5 %, and the
  // peak error meets the 0.30 m target above the traction floor (0.248 m; at the clamp's limit,
  // 96 % of tau_max, 0.271 m; lib/control/README.md).
  TEST_ASSERT_TRUE(on.utilisation() >= 0.95);
  TEST_ASSERT_TRUE(on.max_pos_err_m > 0.248 && on.max_pos_err_m <= 0.30);
  // Without the clamp: the wheels slip, and the distance lost to slip is invisible to the
  // encoders, so the true tracking error never recovers.
  TEST_ASSERT_TRUE(off.slip_steps > 100);
  TEST_ASSERT_TRUE(off.max_odo_err_m > 0.15);
  TEST_ASSERT_TRUE(off.final_pos_err_m > 0.15);
  // With the clamp: no slip, odometry stays true and the loop recovers the reference.
  TEST_ASSERT_EQUAL_INT(0, on.slip_steps);
  TEST_ASSERT_TRUE(on.max_odo_err_m < 0.005);
  TEST_ASSERT_TRUE(on.final_pos_err_m < 0.01);
  TEST_ASSERT_TRUE(on.final_pos_err_m < 0.1 * off.final_pos_err_m);
}

// The same at 48 rad/s^2, where the motor is far from its speed limit.
void test_ii63_clamp_at_48() {
  const ReferenceSpec ref = straight_profile(tbl::kWheelR_m, 48.0f);
  const sim::Result off = run_float(ref, false, 0, 0, 0, 8.0);
  const sim::Result on = run_float(ref, true, 0, 0, 0, 8.0);
  printf("48 rad/s^2: clamp off max %.3f m final %.4f m; clamp on max %.3f m final %.4f m\n",
         off.max_pos_err_m, off.final_pos_err_m, on.max_pos_err_m, on.final_pos_err_m);
  TEST_ASSERT_TRUE(off.slip_steps > 0);
  TEST_ASSERT_EQUAL_INT(0, on.slip_steps);
  TEST_ASSERT_TRUE(on.final_pos_err_m < 0.2 * off.final_pos_err_m);
}

int main() {
  UNITY_BEGIN();
  RUN_TEST(test_line_converges_from_offset);
  RUN_TEST(test_arc_converges_from_offset);
  RUN_TEST(test_figure_eight_converges_from_offset);
  RUN_TEST(test_ii62_clamp_off_slip_threshold);
  RUN_TEST(test_ii62_thesis_controller);
  RUN_TEST(test_ii63_clamp_prevents_slip_at_72);
  RUN_TEST(test_ii63_clamp_at_48);
  return UNITY_END();
}
