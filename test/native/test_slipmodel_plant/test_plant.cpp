// The Euler slip plant: II.6.1, analytic limits, stick/slip behaviour, energy, convergence.
#include <math.h>
#include <stdio.h>
#include <unity.h>

#include "../expect_near.h"

#include <slipmodel/plant.h>
#include <slipmodel/rolling.h>
#include <slipmodel/traction.h>

using namespace slip;


static const double kDt = 5e-4;

void setUp(void) {}
void tearDown(void) {}

struct RunResult {
  PlantState end;
  int slip_steps_r, slip_steps_l;  // steps that ended slipping
  int transitions;                 // stick<->slip changes of either wheel
};

static RunResult run_torque(Plant& pl, double tau_r, double tau_l, double T, double dt = kDt) {
  RunResult res = {PlantState(), 0, 0, 0};
  bool prev_r = pl.state().slipping_r, prev_l = pl.state().slipping_l;
  const long n = lround(T / dt);
  for (long k = 0; k < n; ++k) {
    pl.step_torque(tau_r, tau_l, dt);
    const PlantState& s = pl.state();
    res.slip_steps_r += s.slipping_r;
    res.slip_steps_l += s.slipping_l;
    res.transitions += (s.slipping_r != prev_r) + (s.slipping_l != prev_l);
    prev_r = s.slipping_r;
    prev_l = s.slipping_l;
  }
  res.end = pl.state();
  return res;
}

// The pure-rolling model (rolling.h), integrated with the same semi-implicit Euler.
static double pure_rolling_x(const RobotParams& p, double tau, double T, double dt = kDt) {
  double v = 0.0, x = 0.0;
  const long n = lround(T / dt);
  for (long k = 0; k < n; ++k) {
    v += dt * pure_rolling_accel(p, v, 0.0, tau, tau).dv_m_s2;
    x += dt * v;
  }
  return x;
}

static double table_tau_max() {
  const RobotParams p;
  return tau_max(p, normal_forces(p).N_r);
}

// ---- II.6.1 -------------------------------------------------------------------------------

static void test_ii61_0p09_equals_pure_rolling(void) {
  Plant pl;
  const RunResult r = run_torque(pl, 0.09, 0.09, 2.0);
  TEST_ASSERT_EQUAL_INT(0, r.slip_steps_r + r.slip_steps_l);
  EXPECT_NEAR(1e-3, pure_rolling_x(RobotParams(), 0.09, 2.0), r.end.x_m);
  EXPECT_NEAR(1e-9, 0.0, r.end.y_m);
}

static void test_ii61_0p1_slips_and_travels_less(void) {
  Plant pl;
  const RunResult r = run_torque(pl, 0.1, 0.1, 2.0);
  TEST_ASSERT_TRUE(r.slip_steps_r > 3900 && r.slip_steps_l > 3900);  // slips from the start
  const double x_roll = pure_rolling_x(RobotParams(), 0.1, 2.0);
  char msg[96];
  snprintf(msg, sizeof(msg), "0.1 N m: slip x = %.4f m, pure rolling x = %.4f m", r.end.x_m, x_roll);
  TEST_MESSAGE(msg);
  TEST_ASSERT_TRUE(r.end.x_m < x_roll - 0.1);
}

static void test_ii61_0p3_same_distance_faster_wheels(void) {
  Plant a, b;
  const RunResult r1 = run_torque(a, 0.1, 0.1, 2.0);
  const RunResult r3 = run_torque(b, 0.3, 0.3, 2.0);
  EXPECT_NEAR(0.01 * r1.end.x_m, r1.end.x_m, r3.end.x_m);  // "about as far": within 1 %
  TEST_ASSERT_TRUE(r3.end.dtheta_r_rad_s > 3.0 * r1.end.dtheta_r_rad_s);
  TEST_ASSERT_TRUE(r3.end.x_m < pure_rolling_x(RobotParams(), 0.3, 2.0) / 2.0);
}

// ---- analytic limits ----------------------------------------------------------------------

static void test_pure_rolling_straight_acceleration(void) {
  const RobotParams p;
  const double tau = 0.05;
  const double a = 2.0 * tau / (p.r * (p.m_t() + 2.0 * p.I_wy / (p.r * p.r)));
  Plant pl;
  run_torque(pl, tau, tau, 1.0);
  EXPECT_NEAR(1e-9 * a, a, pl.state().v_m_s / 1.0);
  EXPECT_NEAR(1e-9, pl.state().v_m_s / p.r, pl.state().dtheta_r_rad_s);  // rolling: v = r dtheta
}

static void test_full_slip_accelerations(void) {
  const RobotParams p;
  const double tau = 0.3, N = normal_forces(p).N_r;
  Plant pl;
  run_torque(pl, tau, tau, 0.1);  // broken loose
  const PlantState s0 = pl.state();
  run_torque(pl, tau, tau, 1.0);
  const PlantState s1 = pl.state();
  EXPECT_NEAR(1e-9, 2.0 * p.mu_k * N / p.m_t(), (s1.v_m_s - s0.v_m_s) / 1.0);
  EXPECT_NEAR(1e-7, (tau - p.r * p.mu_k * N) / p.I_wy, (s1.dtheta_r_rad_s - s0.dtheta_r_rad_s) / 1.0);
}

static void test_symmetric_torques_no_yaw(void) {
  const double taus[] = {0.05, 0.0924, 0.1, 0.3, -0.2};
  for (double tau : taus) {
    Plant pl;
    pl.reset(0.3, -0.2, 1.0);
    run_torque(pl, tau, tau, 2.0);
    EXPECT_NEAR(1e-12, 1.0, pl.state().phi_rad);
    EXPECT_NEAR(1e-12, 0.0, pl.state().omega_rad_s);
    EXPECT_NEAR(1e-12, 0.0, pl.state().w_m_s);
    // moved along the heading only
    EXPECT_NEAR(1e-9, tan(1.0) * (pl.state().x_m - 0.3), pl.state().y_m + 0.2);
  }
}

static void test_faster_right_wheel_turns_left(void) {
  const double pairs[][2] = {{0.06, 0.03}, {0.3, 0.1}, {0.0, -0.05}};
  for (const auto& tl : pairs) {
    Plant pl;
    pl.step_torque(tl[0], tl[1], kDt);
    TEST_ASSERT_TRUE(pl.state().omega_rad_s > 0.0);
    run_torque(pl, tl[0], tl[1], 0.5);
    TEST_ASSERT_TRUE(pl.state().phi_rad > 0.0);
    TEST_ASSERT_TRUE(pl.state().dtheta_r_rad_s > pl.state().dtheta_l_rad_s);
    // mirrored command turns right by the same amount
    Plant mir;
    run_torque(mir, tl[1], tl[0], 0.5 + kDt);
    EXPECT_NEAR(1e-9, -pl.state().phi_rad, mir.state().phi_rad);
  }
}

static void test_pure_rolling_turn_matches_rolling_model(void) {
  // A gentle turn that never slips follows the derived pure-rolling yaw dynamics.
  const RobotParams p;
  Plant pl;
  double v = 0.0, om = 0.0;
  for (int k = 0; k < 2000; ++k) {
    const RollingAccel a = pure_rolling_accel(p, v, om, 0.03, 0.01);
    v += kDt * a.dv_m_s2;
    om += kDt * a.domega_rad_s2;
    pl.step_torque(0.03, 0.01, kDt);
    TEST_ASSERT_FALSE(pl.state().slipping_r || pl.state().slipping_l);
  }
  EXPECT_NEAR(1e-3 * fabs(om), om, pl.state().omega_rad_s);
  EXPECT_NEAR(1e-3 * fabs(v), v, pl.state().v_m_s);
}

// ---- energy -------------------------------------------------------------------------------

static void check_energy_never_increases(Plant& pl, double T) {
  double e = pl.kinetic_energy_j();
  const double e0 = e;
  const long n = lround(T / kDt);
  for (long k = 0; k < n; ++k) {
    pl.step_torque(0.0, 0.0, kDt);
    const double e1 = pl.kinetic_energy_j();
    char msg[96];
    snprintf(msg, sizeof(msg), "step %ld: energy rose from %.15g to %.15g J", k, e, e1);
    TEST_ASSERT_MESSAGE(e1 <= e * (1.0 + 1e-12) + 1e-15, msg);
    e = e1;
  }
  TEST_ASSERT_TRUE(e < e0 || e0 == 0.0);
}

static void test_energy_never_increases_without_input(void) {
  Plant a;  // wheels spinning on the spot
  a.set_velocity(0.0, 0.0, 0.0, 60.0, 40.0);
  check_energy_never_increases(a, 2.0);
  Plant b;  // sliding sideways while spinning about the vertical axis
  b.set_velocity(0.5, 0.8, 6.0, 0.0, 0.0);
  check_energy_never_increases(b, 2.0);
  Plant c;  // rolling in a turn (stuck wheels): energy may only stay or fall
  c.set_velocity(0.5, 0.0, 2.0, (0.5 + table::b * 2.0) / table::r, (0.5 - table::b * 2.0) / table::r);
  check_energy_never_increases(c, 2.0);
  Plant d;  // fast turn: lateral slip, both wheels slide
  d.set_velocity(1.5, 0.0, 8.0, (1.5 + table::b * 8.0) / table::r, (1.5 - table::b * 8.0) / table::r);
  check_energy_never_increases(d, 2.0);
}

// ---- stick / slip -------------------------------------------------------------------------

static void test_just_below_tau_max_never_slips(void) {
  Plant pl;
  const RunResult r = run_torque(pl, 0.999 * table_tau_max(), 0.999 * table_tau_max(), 2.0);
  TEST_ASSERT_EQUAL_INT(0, r.slip_steps_r + r.slip_steps_l);
}

static void test_just_above_tau_max_always_slips(void) {
  Plant pl;
  const RunResult r = run_torque(pl, 1.001 * table_tau_max(), 1.001 * table_tau_max(), 2.0);
  TEST_ASSERT_EQUAL_INT(4000, r.slip_steps_r);
  TEST_ASSERT_EQUAL_INT(4000, r.slip_steps_l);
  TEST_ASSERT_EQUAL_INT(2, r.transitions);  // each wheel breaks loose once, at the first step
}

static void test_restick_without_chattering(void) {
  // Spin the wheels, then hold a torque that rolling can carry: the wheels re-stick once and
  // stay stuck (one transition per wheel, no chattering at zero slip).
  Plant pl;
  pl.set_velocity(0.0, 0.0, 0.0, 20.0, 20.0);
  const RunResult r = run_torque(pl, 0.05, 0.05, 2.0);
  TEST_ASSERT_EQUAL_INT(2, r.transitions);
  TEST_ASSERT_FALSE(r.end.slipping_r || r.end.slipping_l);
  EXPECT_NEAR(1e-9, r.end.v_m_s, table::r * r.end.dtheta_r_rad_s);
  // Coasting to rest: wheels stop with the body and stay stuck, no sign flips.
  Plant c;
  c.set_velocity(0.3, 0.0, 0.0, 0.0, 0.0);  // skidding with locked wheels
  const RunResult rc = run_torque(c, 0.0, 0.0, 1.0);
  TEST_ASSERT_EQUAL_INT(2, rc.transitions);
  TEST_ASSERT_TRUE(rc.end.v_m_s > 0.0);  // never driven backwards
}

static void test_kinetic_stiction_hysteresis(void) {
  // Between tau_k = tau_max mu_k/mu_s and tau_max a stuck wheel stays stuck and a slipping
  // wheel keeps slipping (mu_k < mu_s).
  const RobotParams p;
  const double tau = 0.5 * (table_tau_max() * p.mu_k / p.mu_s + table_tau_max());
  Plant stuck;
  TEST_ASSERT_EQUAL_INT(0, run_torque(stuck, tau, tau, 1.0).slip_steps_r);
  Plant slipping;
  slipping.set_velocity(0.0, 0.0, 0.0, 5.0, 5.0);
  TEST_ASSERT_EQUAL_INT(2000, run_torque(slipping, tau, tau, 1.0).slip_steps_r);
}

// ---- step size ----------------------------------------------------------------------------

static void test_step_size_convergence(void) {
  // 2 s slipping turn (right 0.3 N m, left 0.1 N m). Semi-implicit Euler is first order: the
  // change from halving dt must halve with dt, and at dt = 0.5 ms stay below the stated bound.
  PlantState s[3];
  const double dts[3] = {1e-3, 5e-4, 2.5e-4};
  for (int i = 0; i < 3; ++i) {
    Plant pl;
    run_torque(pl, 0.3, 0.1, 2.0, dts[i]);
    s[i] = pl.state();
  }
  const double d01 = hypot(s[0].x_m - s[1].x_m, s[0].y_m - s[1].y_m);
  const double d12 = hypot(s[1].x_m - s[2].x_m, s[1].y_m - s[2].y_m);
  const double p01 = fabs(s[0].phi_rad - s[1].phi_rad), p12 = fabs(s[1].phi_rad - s[2].phi_rad);
  char msg[160];
  snprintf(msg, sizeof(msg), "halving dt: |dpos| %.3g -> %.3g m, |dphi| %.3g -> %.3g rad", d01, d12,
           p01, p12);
  TEST_MESSAGE(msg);
  TEST_ASSERT_TRUE(d12 < 2e-3);   // stated bound (README): < 2 mm position
  TEST_ASSERT_TRUE(p12 < 5e-3);   // and < 5 mrad heading over 2 s
  TEST_ASSERT_TRUE(d12 < 0.7 * d01);
}


static void test_combined_slip_friction_and_lateral_transfer(void) {
  // A fast coasting left turn: the centripetal force needed exceeds the static limit, both wheels
  // slide with longitudinal and lateral slip, and each contact force has magnitude mu_k N
  // opposite its slip velocity (II.36-II.39). The lateral force loads the outer (right) wheel (II.28).
  const RobotParams p;
  Plant pl;
  const double v = 1.5, om = 8.0;
  pl.set_velocity(v, 0.0, om, (v + p.b * om) / p.r, (v - p.b * om) / p.r);
  pl.step_torque(0.0, 0.0, kDt);
  const double lat1 = pl.state().L_r_n + pl.state().L_l_n;
  pl.step_torque(0.0, 0.0, kDt);
  const PlantState& s = pl.state();
  TEST_ASSERT_TRUE(s.slipping_r && s.slipping_l);
  TEST_ASSERT_TRUE(s.w_m_s < 0.0);  // drifts outwards (to the right of a left turn)
  EXPECT_NEAR(1e-12, p.mu_k * s.N_r, hypot(s.F_r_n, s.L_r_n));
  EXPECT_NEAR(1e-12, p.mu_k * s.N_l, hypot(s.F_l_n, s.L_l_n));
  TEST_ASSERT_TRUE(s.L_r_n > 0.0 && s.L_l_n > 0.0);  // friction opposes the outward drift
  TEST_ASSERT_TRUE(s.N_r > s.N_l);
  EXPECT_NEAR(1e-12, p.h * lat1, (s.N_r - s.N_l) * p.b);  // II.28 with the previous step's force
}

static void test_rolling_turn_lateral_transfer(void) {
  // A gentle left turn in pure rolling: the wheels hold the centripetal force laterally, and
  // II.28 moves load to the right wheel.
  Plant pl;
  run_torque(pl, 0.03, 0.01, 1.0);
  const PlantState& s = pl.state();
  TEST_ASSERT_FALSE(s.slipping_r || s.slipping_l);
  EXPECT_NEAR(1e-12, 0.0, s.w_m_s);
  TEST_ASSERT_TRUE(s.L_r_n + s.L_l_n > 0.0);
  TEST_ASSERT_TRUE(s.N_r > s.N_l);
}


static void test_no_flag_chatter_over_torque_grid(void) {
  // Constant torque pairs over [-0.15, 0.15]^2 N m for 2 s: stick/slip changes stay few. This
  // guards the lateral split by remaining friction capacity: a split by normal force alone made
  // turns near the limit alternate the slipping wheel every step (2655 changes at 0.0375/0.0625).
  int worst = 0;
  double worst_r = 0.0, worst_l = 0.0;
  for (int i = -12; i <= 12; ++i) {
    for (int j = -12; j <= 12; ++j) {
      Plant pl;
      const RunResult r = run_torque(pl, 0.0125 * i, 0.0125 * j, 2.0);
      if (r.transitions > worst) { worst = r.transitions; worst_r = 0.0125 * i; worst_l = 0.0125 * j; }
    }
  }
  char msg[96];
  snprintf(msg, sizeof(msg), "worst: %d stick/slip changes in 2 s at (%.4f, %.4f) N m", worst, worst_r, worst_l);
  TEST_MESSAGE(msg);
  TEST_ASSERT_TRUE(worst <= 10);
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_ii61_0p09_equals_pure_rolling);
  RUN_TEST(test_ii61_0p1_slips_and_travels_less);
  RUN_TEST(test_ii61_0p3_same_distance_faster_wheels);
  RUN_TEST(test_pure_rolling_straight_acceleration);
  RUN_TEST(test_full_slip_accelerations);
  RUN_TEST(test_symmetric_torques_no_yaw);
  RUN_TEST(test_faster_right_wheel_turns_left);
  RUN_TEST(test_pure_rolling_turn_matches_rolling_model);
  RUN_TEST(test_energy_never_increases_without_input);
  RUN_TEST(test_just_below_tau_max_never_slips);
  RUN_TEST(test_just_above_tau_max_always_slips);
  RUN_TEST(test_restick_without_chattering);
  RUN_TEST(test_kinetic_stiction_hysteresis);
  RUN_TEST(test_step_size_convergence);
  RUN_TEST(test_combined_slip_friction_and_lateral_transfer);
  RUN_TEST(test_rolling_turn_lateral_transfer);
  RUN_TEST(test_no_flag_chatter_over_torque_grid);
  return UNITY_END();
}
