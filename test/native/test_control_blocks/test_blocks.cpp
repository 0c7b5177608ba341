// The blocks of the cascade against limits solvable by hand: signs of the torque split against
// the plant, clamp, torque->PWM inverse of the slipmodel motor, the kinematic law and its
// Lyapunov function, anti-windup, references, and the fixed-point helpers' error bounds.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include <unity.h>

#include "../expect_near.h"
#include "../table.h"

#include <control/cascade.h>
#include <control/cascade_q.h>
#include <control/fixmath.h>
#include <control/reference.h>
#include <slipmodel/motor.h>
#include <slipmodel/plant.h>
#include <slipmodel/rolling.h>

using namespace ctl;

namespace {
const double kPi = 3.14159265358979323846;
}  // namespace

void setUp() {}
void tearDown() {}

void test_split_inverts_and_matches_plant_signs() {
  const float r = tbl::kWheelR_m, b = tbl::kHalfTrack_m;
  // Inverse: (tau_r + tau_l)/r = F and b (tau_r - tau_l)/r = M.
  const WheelPair t = split_torque(r, b, 3.0f, 0.2f);
  CHECK_NEAR(3.0, (t.r + t.l) / r, 1e-5, "F");
  CHECK_NEAR(0.2, b * (t.r - t.l) / r, 1e-6, "M");
  // A positive yaw moment must turn the plant left (omega > 0): tau_r > tau_l.
  const WheelPair turn = split_torque(r, b, 0.0f, 0.05f);
  TEST_ASSERT_TRUE(turn.r > 0.0f && turn.l < 0.0f);
  slip::Plant pl;
  pl.reset(0, 0, 0);
  for (int i = 0; i < 200; ++i) pl.step_torque(turn.r, turn.l, 5e-4);
  TEST_ASSERT_TRUE(pl.state().omega_rad_s > 0.0);
  // And the rolling model's yaw acceleration equals M / I_eff (v = omega = 0).
  const slip::RollingAccel a = slip::pure_rolling_accel(slip::RobotParams(), 0, 0, turn.r, turn.l);
  CHECK_NEAR(0.05 / slip::rolling_yaw_inertia_kgm2(slip::RobotParams()), a.domega_rad_s2, 1e-4, "domega");
}

void test_clamp() {
  bool c = false;
  TEST_ASSERT_EQUAL_FLOAT(0.09f, clamp_torque(0.2f, 0.09f, &c));
  TEST_ASSERT_TRUE(c);
  TEST_ASSERT_EQUAL_FLOAT(-0.09f, clamp_torque(-0.2f, 0.09f, &c));
  TEST_ASSERT_TRUE(c);
  TEST_ASSERT_EQUAL_FLOAT(0.05f, clamp_torque(0.05f, 0.09f, &c));
  TEST_ASSERT_FALSE(c);
  TEST_ASSERT_EQUAL_FLOAT(0.0f, clamp_torque(NAN, 0.09f, &c));
  TEST_ASSERT_TRUE(c);
  TEST_ASSERT_EQUAL_FLOAT(0.0f, clamp_torque(0.05f, NAN, &c));  // no limit known: no torque
}

void test_pwm_is_inverse_of_motor_model() {
  const slip::MotorParams m;
  bool sat = false;
  for (double w = -30; w <= 30; w += 7.5)
    for (double tau = -0.3; tau <= 0.3; tau += 0.05) {
      const float u = torque_to_pwm(m, static_cast<float>(tau), static_cast<float>(w), &sat);
      if (!sat) CHECK_NEAR(tau, slip::motor_torque_nm(m, u, w), 1e-6, "motor(pwm(tau))");
    }
  // Back-EMF compensation: zero torque at speed needs u = w / no_load.
  CHECK_NEAR(20.0 / m.no_load_rad_s, torque_to_pwm(m, 0.0f, 20.0f, &sat), 1e-6, "u for zero torque");
  // Saturation.
  TEST_ASSERT_EQUAL_FLOAT(1.0f, torque_to_pwm(m, 5.0f, 0.0f, &sat));
  TEST_ASSERT_TRUE(sat);
  TEST_ASSERT_EQUAL_FLOAT(-1.0f, torque_to_pwm(m, -0.5f, -30.0f, &sat));
  TEST_ASSERT_TRUE(sat);
}

void test_kinematic_law_hand_limits() {
  const Gains g = default_gains();
  // On the reference: v_d = v_r, omega_d = omega_r.
  KinematicOut k = kinematic_law(g, Pose{1, 2, 0.5f}, RefSample{1, 2, 0.5f, 0.4f, 0.3f, 0, 0}, 2, 20);
  CHECK_NEAR(0.4, k.v_d_m_s, 1e-6, "v_d on ref");
  CHECK_NEAR(0.3, k.omega_d_rad_s, 1e-6, "omega_d on ref");
  // Reference 0.1 m ahead along the robot's heading (phi = pi/2): e_x = +0.1, speed up.
  k = kinematic_law(g, Pose{0, 0, static_cast<float>(kPi / 2)}, RefSample{0, 0.1f, static_cast<float>(kPi / 2), 0.4f, 0, 0, 0}, 2, 20);
  CHECK_NEAR(0.1, k.e_x_m, 1e-6, "e_x");
  CHECK_NEAR(0.0, k.e_y_m, 1e-6, "e_y");
  CHECK_NEAR(0.4 + g.k_x * 0.1, k.v_d_m_s, 1e-5, "v_d");
  // Reference to the robot's left: e_y > 0, turn left (omega_d > 0).
  k = kinematic_law(g, Pose{0, 0, 0}, RefSample{0, 0.1f, 0, 0.4f, 0, 0, 0}, 2, 20);
  CHECK_NEAR(0.1, k.e_y_m, 1e-6, "e_y left");
  CHECK_NEAR(0.4 * g.k_y * 0.1, k.omega_d_rad_s, 1e-5, "omega_d left");
  // Heading error wraps: phi_r = pi - 0.1, phi = -pi + 0.1 -> e_phi = -0.2.
  k = kinematic_law(g, Pose{0, 0, static_cast<float>(-kPi + 0.1)}, RefSample{0, 0, static_cast<float>(kPi - 0.1), 0, 0, 0, 0}, 2, 20);
  CHECK_NEAR(-0.2, k.e_phi_rad, 1e-5, "e_phi wrap");
}

// Continuous-time unicycle driven by II.44 (v = v_d, omega = omega_d): V of II.42 never grows.
void test_lyapunov_function_decreases() {
  const Gains g = default_gains();
  srand(3);
  for (int trial = 0; trial < 20; ++trial) {
    double x = (rand() % 200 - 100) / 200.0, y = (rand() % 200 - 100) / 200.0, phi = (rand() % 200 - 100) / 80.0;
    const double v_r = 0.3, w_r = (rand() % 100 - 50) / 100.0, dt = 1e-4;
    double xr = 0, yr = 0, phir = 0, v_prev = 1e9;
    for (int k = 0; k < 200000; ++k) {  // 20 s
      const RefSample ref{static_cast<float>(xr), static_cast<float>(yr), static_cast<float>(phir),
                          static_cast<float>(v_r), static_cast<float>(w_r), 0, 0};
      const KinematicOut o = kinematic_law(g, Pose{static_cast<float>(x), static_cast<float>(y), static_cast<float>(phi)}, ref, 100, 100);
      const double V = 0.5 * (o.e_x_m * o.e_x_m + o.e_y_m * o.e_y_m) + (1 - cos(o.e_phi_rad)) / g.k_y;
      if (!(V <= v_prev + 1e-7)) printf("V rose: %.9g -> %.9g at step %d\n", v_prev, V, k);
      TEST_ASSERT_TRUE(V <= v_prev + 1e-7);
      v_prev = V;
      x += dt * o.v_d_m_s * cos(phi);
      y += dt * o.v_d_m_s * sin(phi);
      phi += dt * o.omega_d_rad_s;
      xr += dt * v_r * cos(phir);
      yr += dt * v_r * sin(phir);
      phir += dt * w_r;
    }
    if (!(v_prev < 1e-4)) printf("trial %d: V after 20 s %.3g\n", trial, v_prev);
    TEST_ASSERT_TRUE(v_prev < 1e-4);  // and converges (LaSalle, v_r != 0)
  }
}

// A wheel held against its limit must not wind the integrators up.
void test_anti_windup() {
  for (int fixed = 0; fixed < 2; ++fixed) {
    const ControlConfig cfg = make_control_config(slip::RobotParams(), slip::MotorParams(), default_gains(), true);
    Controller f(cfg);
    ControllerQ q{ControlConfigQ(cfg)};
    // Robot blocked (encoders do not move) while the reference runs away at 1 m/s.
    const RefSample ref{10.0f, 0, 0, 1.0f, 0, 0, 0};
    const RefSampleQ refq{10 << 20, 0, 0, 4096, 0, 0, 0};
    for (int k = 0; k < 400; ++k) {
      if (fixed) { q.inner_step(0, 0, 25000); q.outer_step(refq); }
      else { f.inner_step(0, 0, 0.025f); f.outer_step(ref); }
    }
    const double i_v = fixed ? q.integ_v_q16() / 65536.0 : f.integ_v_n();
    const bool clamped = fixed ? q.inner().clamped_r : f.inner().clamped_r;
    printf("anti-windup (%s): blocked 10 s, integrator %.3f N (limit %.1f N)\n", fixed ? "fixed" : "float", i_v, cfg.integ_max_n);
    TEST_ASSERT_TRUE(clamped);
    // Integration stops once the wheel torque hits tau_max: the integrator holds what was
    // needed to reach the limit, far below its own bound.
    TEST_ASSERT_TRUE(fabs(i_v) < 0.25 * cfg.integ_max_n);
  }
}

// Clamp off: a blocked robot with a small speed error first integrates (nothing limits yet),
// then the duty saturates and the integrator must freeze below its own bound.
void test_anti_windup_on_duty_saturation() {
  for (int fixed = 0; fixed < 2; ++fixed) {
    const ControlConfig cfg = make_control_config(slip::RobotParams(), slip::MotorParams(), default_gains(), false);
    Controller f(cfg);
    ControllerQ q{ControlConfigQ(cfg)};
    const RefSample ref{0.05f, 0, 0, 1.2f, 0, 0, 0};  // 5 cm ahead, 1.2 m/s
    const RefSampleQ refq{static_cast<int32_t>(0.05 * 1048576), 0, 0, static_cast<int16_t>(1.2 * 4096), 0, 0, 0};
    double i_mid = 0;
    bool sat = false;
    for (int k = 0; k < 800; ++k) {
      if (fixed) { q.inner_step(0, 0, 25000); q.outer_step(refq); }
      else { f.inner_step(0, 0, 0.025f); f.outer_step(ref); }
      if (k == 400) i_mid = fixed ? q.integ_v_q16() / 65536.0 : f.integ_v_n();
    }
    sat = fixed ? q.inner().sat_r : f.inner().sat_r;
    const double i_end = fixed ? q.integ_v_q16() / 65536.0 : f.integ_v_n();
    printf("anti-windup on duty (%s): integrator %.3f N at 10 s, %.3f N at 20 s (bound %.1f N), saturated %d\n",
           fixed ? "fixed" : "float", i_mid, i_end, cfg.integ_max_n, sat);
    TEST_ASSERT_TRUE(sat);
    TEST_ASSERT_TRUE(i_mid > 0.5);                       // it did integrate before saturating
    CHECK_NEAR(i_mid, i_end, 1e-3, "frozen while saturated");
    TEST_ASSERT_TRUE(i_end < 0.9 * cfg.integ_max_n);     // stopped by saturation, not by its bound
  }
}

void test_references() {
  // Thesis straight profile: 72 rad/s^2 for 0.5 s -> 36 rad/s wheel speed.
  const double r = tbl::kWheelR_m;
  const ReferenceSpec s = straight_profile(tbl::kWheelR_m, 72.0f);
  CHECK_NEAR(r * 36.0, reference_at(s, 0.5f).v_m_s, 1e-5, "cruise speed");
  CHECK_NEAR(r * 72.0, reference_at(s, 0.25f).dv_m_s2, 1e-5, "acceleration");
  CHECK_NEAR(0.0, reference_at(s, 0.6f).dv_m_s2, 0, "hold");
  CHECK_NEAR(0.5 * r * 72 * 0.25 + r * 36 * 0.5, reference_at(s, 1.0f).x_m, 1e-5, "distance");
  // Arc: stays on the circle centred (0, R); heading is tangent; omega = v / R.
  const ReferenceSpec arc{PathKind::kArc, 0.5f, 0.4f, -0.5f};
  for (float t = 0; t < 10; t += 0.37f) {
    const RefSample r = reference_at(arc, t);
    CHECK_NEAR(0.5, hypot(r.x_m, r.y_m + 0.5), 1e-4, "on circle");
    CHECK_NEAR(r.v_m_s / -0.5, r.omega_rad_s, 1e-5, "omega");
  }
  // Figure eight (phi = beta sin tau, kappa = cos(tau)/R): the numerical derivatives of the pose
  // agree with (v cos phi, v sin phi, omega), that of omega with domega (the v^2 dkappa/du term
  // included), and omega is continuous (an eight of two circles jumps by 2 v/R = 1.33
  // rad/s at each crossing); |kappa| <= 1/|R|. Both signs of R (R < 0 mirrors in y).
  const float radii[] = {0.6f, -0.6f};
  for (float R : radii) {
    const ReferenceSpec e8{PathKind::kFigureEight, 0.5f, 0.4f, R};
    const float h = 1e-3f;
    for (float t = 1.0f; t < 30.0f; t += 0.173f) {
      const RefSample a = reference_at(e8, t - h), m = reference_at(e8, t), b = reference_at(e8, t + h);
      CHECK_NEAR(m.v_m_s * cos(m.phi_rad), (b.x_m - a.x_m) / (2 * h), 2e-3, "dx/dt");
      CHECK_NEAR(m.v_m_s * sin(m.phi_rad), (b.y_m - a.y_m) / (2 * h), 2e-3, "dy/dt");
      CHECK_NEAR(m.omega_rad_s, (b.phi_rad - a.phi_rad) / (2 * h), 2e-3, "dphi/dt");
      CHECK_NEAR(m.domega_rad_s2, (b.omega_rad_s - a.omega_rad_s) / (2 * h), 5e-3, "domega/dt");
      TEST_ASSERT_TRUE(fabs(m.omega_rad_s) <= m.v_m_s / fabs(R) * (1 + 1e-6));
    }
    double max_jump = 0;
    RefSample prev = reference_at(e8, 0.0f);
    for (int k = 1; k <= 30000; ++k) {  // 30 s in 1 ms steps (3 crossings, 3 lobe ends)
      const RefSample r = reference_at(e8, k * 1e-3f);
      max_jump = fmax(max_jump, fabs(r.omega_rad_s - prev.omega_rad_s));
      prev = r;
    }
    // |domega/dt| <= dv/|R| + v^2/(beta R^2) = 0.83 + 0.18 rad/s^2: <= 1.0e-3 rad/s per ms.
    printf("figure eight R %.1f: largest omega step in 1 ms %.2e rad/s\n", R, max_jump);
    TEST_ASSERT_TRUE(max_jump < 1.1e-3);
    // Shape (reference.h): closes after L = 2 pi beta |R| with heading 0; crosses itself at
    // (0, 2.832 R) with heading +-beta at L/4 and 3L/4. At cruise, s = 0.16 + 0.4 (t - 0.8).
    const double L = 2 * kPi * 2.4048255576957724 * fabs(R);
    const RefSample c = reference_at(e8, static_cast<float>((L - 0.16) / 0.4 + 0.8));
    CHECK_NEAR(0.0, c.x_m, 1e-5, "closed: x");
    CHECK_NEAR(0.0, c.y_m, 1e-5, "closed: y");
    CHECK_NEAR(0.0, c.phi_rad, 1e-5, "closed: heading");
    const RefSample c1 = reference_at(e8, static_cast<float>((L / 4 - 0.16) / 0.4 + 0.8));
    const RefSample c3 = reference_at(e8, static_cast<float>((3 * L / 4 - 0.16) / 0.4 + 0.8));
    CHECK_NEAR(0.0, c1.x_m, 1e-5, "crossing 1: x");
    CHECK_NEAR(2.8321431786 * R, c1.y_m, 1e-5, "crossing 1: y");
    CHECK_NEAR(0.0, c3.x_m, 1e-5, "crossing 2: x");
    CHECK_NEAR(2.8321431786 * R, c3.y_m, 1e-5, "crossing 2: y");
    CHECK_NEAR((R > 0 ? 1 : -1) * 2.4048255576957724, c1.phi_rad, 1e-5, "crossing 1: heading");
    CHECK_NEAR((R > 0 ? -1 : 1) * 2.4048255576957724, c3.phi_rad, 1e-5, "crossing 2: heading");
    CHECK_NEAR(0.0, c1.omega_rad_s, 1e-5, "inflection at the crossing");
  }
  // Invalid spec -> at rest.
  TEST_ASSERT_EQUAL_FLOAT(0.0f, reference_at(ReferenceSpec{PathKind::kArc, 0.5f, 0.4f, 0.0f}, 3.0f).v_m_s);
  TEST_ASSERT_EQUAL_FLOAT(0.0f, reference_at(ReferenceSpec{PathKind::kLine, -1.0f, 0.4f, 0.0f}, 3.0f).x_m);
}

void test_fixed_point_helpers() {
  // sin/cos over a dense sweep: |error| <= 3.5e-5 (stated in fixmath.h).
  double max_err = 0;
  for (uint32_t k = 0; k < 200000; ++k) {
    const uint32_t a = k * 21475u + (k >> 3);
    const double ang = a * (2 * kPi / 4294967296.0);
    max_err = fmax(max_err, fabs(fx::sin_q15(a) / 32767.0 - sin(ang)));
    max_err = fmax(max_err, fabs(fx::cos_q15(a) / 32767.0 - cos(ang)));
  }
  printf("sin/cos Q15 max error %.2e\n", max_err);
  TEST_ASSERT_TRUE(max_err <= 3.5e-5);
  // Multiplies: exact rounding against int64 arithmetic, and saturation instead of wrap.
  srand(5);
  for (int i = 0; i < 100000; ++i) {
    const int32_t a = static_cast<int32_t>((static_cast<uint32_t>(rand()) << 16) ^ static_cast<uint32_t>(rand())) >> (i % 20);
    const int16_t b = static_cast<int16_t>(rand());
    const int64_t exact = (static_cast<int64_t>(a) * b + (1LL << 11)) >> 12;
    const int32_t got = fx::mul32x16<12>(a, b);
    if (exact > INT32_MAX) TEST_ASSERT_EQUAL_INT32(INT32_MAX, got);
    else if (exact < INT32_MIN) TEST_ASSERT_EQUAL_INT32(INT32_MIN, got);
    else TEST_ASSERT_EQUAL_INT32(static_cast<int32_t>(exact), got);
    const int16_t c = static_cast<int16_t>(rand());
    TEST_ASSERT_EQUAL_INT32(static_cast<int32_t>((static_cast<int64_t>(b) * c + (1 << 14)) >> 15), fx::mul16<15>(b, c));
  }
  TEST_ASSERT_EQUAL_INT32(INT32_MAX, fx::add_sat32(INT32_MAX - 5, 10));
  TEST_ASSERT_EQUAL_INT32(INT32_MIN, fx::add_sat32(INT32_MIN + 5, -10));
  // Saturating subtraction (the AVR's assembly is checked against the same int64 reference in
  // bench/control_avr), and the plain-C 32x16 product of the inner step's rare paths: equal to
  // mul32x16 for S = 16; for S = 11 its int16 saturation (the 32-bit wheel-rate path) is equal.
  srand(7);
  for (int i = 0; i < 100000; ++i) {
    const int32_t a = static_cast<int32_t>((static_cast<uint32_t>(rand()) << 16) ^ static_cast<uint32_t>(rand())) >> (i % 4);
    const int32_t b = static_cast<int32_t>((static_cast<uint32_t>(rand()) << 16) ^ static_cast<uint32_t>(rand())) >> (i / 4 % 4);
    const int64_t d = static_cast<int64_t>(a) - b;
    TEST_ASSERT_EQUAL_INT32(d > INT32_MAX ? INT32_MAX : (d < INT32_MIN ? INT32_MIN : static_cast<int32_t>(d)), fx::sub_sat32(a, b));
    const int16_t c = static_cast<int16_t>(rand());
    TEST_ASSERT_EQUAL_INT32(fx::mul32x16<16>(a, c), fx::mul32x16_halves<16>(a, c));
    TEST_ASSERT_EQUAL_INT16(fx::sat16(fx::mul32x16<11>(a, c)), fx::sat16(fx::mul32x16_halves<11>(a, c)));
  }
  TEST_ASSERT_EQUAL_INT32(INT32_MAX, fx::sub_sat32(0, INT32_MIN));
  TEST_ASSERT_EQUAL_INT32(INT32_MIN, fx::sub_sat32(-2, INT32_MAX));
  // The AVR's sin_q15 reads the difference of two table entries as one unsigned byte: the
  // quarter-wave table must increase by 0..255 per entry.
  for (int i = 0; i < 256; ++i) {
    const int d = detail::kSinQuarterQ15[i + 1] - detail::kSinQuarterQ15[i];
    TEST_ASSERT_TRUE(d >= 0 && d <= 255);
  }
}

int main() {
  UNITY_BEGIN();
  RUN_TEST(test_split_inverts_and_matches_plant_signs);
  RUN_TEST(test_clamp);
  RUN_TEST(test_pwm_is_inverse_of_motor_model);
  RUN_TEST(test_kinematic_law_hand_limits);
  RUN_TEST(test_lyapunov_function_decreases);
  RUN_TEST(test_anti_windup);
  RUN_TEST(test_anti_windup_on_duty_saturation);
  RUN_TEST(test_references);
  RUN_TEST(test_fixed_point_helpers);
  return UNITY_END();
}
