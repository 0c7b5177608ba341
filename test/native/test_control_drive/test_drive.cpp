// Drive mode's reference source (lib/control/drive.h): acceleration limits, the feed-forward
// it reports, the pose it integrates, the command timeout, and the fixed-point step (the
// firmware's) against the float one.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include <control/drive.h>
#include <unity.h>

#include "../expect_near.h"

using namespace ctl;

namespace {
const uint32_t kDtUs = 50000;  // the outer period
const float kDt = 0.05f;
const DriveLimits kLim{1.0f, 4.0f};
const double kPi = 3.14159265358979323846;

double wrap(double a) { return a - 2 * kPi * floor((a + kPi) / (2 * kPi)); }
}  // namespace

void setUp() {}
void tearDown() {}

void test_targets_in_controller_formats() {
  TEST_ASSERT_EQUAL_INT16(4096, drive_v_q12(1000));
  TEST_ASSERT_EQUAL_INT16(16384, drive_v_q12(4000));
  TEST_ASSERT_EQUAL_INT16(-16384, drive_v_q12(-4000));
  TEST_ASSERT_EQUAL_INT16(-4, drive_v_q12(-1));      // -4.096
  TEST_ASSERT_EQUAL_INT16(2, drive_omega_q11(1));    // 2.048
  TEST_ASSERT_EQUAL_INT16(30720, drive_omega_q11(15000));
  TEST_ASSERT_EQUAL_INT16(-30720, drive_omega_q11(-15000));
  // every value of the Drive ranges: the nearest integer (division-free; a result within 0.07
  // of a half may round either way)
  int exact = 0;
  for (int32_t x = -15000; x <= 15000; ++x) {
    const double w = x * 2.048, f = fabs(w - floor(w)) - 0.5;  // Q16 constant: off by <= 0.062 at 15000
    if (fabs(f) > 0.07) {
      TEST_ASSERT_EQUAL_INT16(static_cast<int16_t>(lround(w)), drive_omega_q11(static_cast<int16_t>(x)));
      ++exact;
    }
    if (x >= -4000 && x <= 4000) {
      const double v = x * 4.096, g = fabs(v - floor(v)) - 0.5;
      if (fabs(g) > 0.07) TEST_ASSERT_EQUAL_INT16(static_cast<int16_t>(lround(v)), drive_v_q12(static_cast<int16_t>(x)));
    }
  }
  TEST_ASSERT_TRUE(exact > 25000);
}

void test_config() {
  const DriveConfigQ c(kLim, kDtUs);
  TEST_ASSERT_TRUE(c.ok);
  TEST_ASSERT_EQUAL_INT16(205, c.dv_step_q12);   // 0.05 m/s
  TEST_ASSERT_EQUAL_INT16(410, c.dw_step_q11);   // 0.2 rad/s
  TEST_ASSERT_EQUAL_INT16(20, c.inv_dt_hz);
  TEST_ASSERT_FALSE(DriveConfigQ(DriveLimits{0.0f, 4.0f}, kDtUs).ok);
  TEST_ASSERT_FALSE(DriveConfigQ(DriveLimits{1.0f, 100.0f}, kDtUs).ok);
  TEST_ASSERT_FALSE(DriveConfigQ(kLim, 200000).ok);  // dt/2 2^8 does not fit Q12
}

// The speed ramps at the limit, reports the limit as its acceleration, and holds the target.
void test_ramps_within_limits() {
  DriveReference f(kLim, kDt);
  const DriveConfigQ c(kLim, kDtUs);
  DriveReferenceQ q;
  const int16_t vt = drive_v_q12(600), wt = drive_omega_q11(-1000);
  for (int k = 0; k < 20; ++k) {
    const RefSample s = f.step(0.6f, -1.0f);
    const RefSampleQ sq = q.step(c, vt, wt);
    const double v_exp = fmin(0.05 * k, 0.6), w_exp = -fmin(0.2 * k, 1.0);
    EXPECT_NEAR(1e-5, v_exp, s.v_m_s);
    EXPECT_NEAR(1e-5, w_exp, s.omega_rad_s);
    EXPECT_NEAR(1e-5, k < 12 ? 1.0 : 0.0, s.dv_m_s2);      // 12 ticks of 0.05 m/s
    EXPECT_NEAR(1e-5, k < 5 ? -4.0 : 0.0, s.domega_rad_s2);  // 5 ticks of 0.2 rad/s
    EXPECT_NEAR(2e-3, v_exp, sq.v_q12 / 4096.0);
    EXPECT_NEAR(3e-3, w_exp, sq.omega_q11 / 2048.0);
    EXPECT_NEAR(0.01, s.dv_m_s2, sq.dv_q12 / 4096.0);
  }
  // at the target, then back to 0 (the timeout's target): the same ramp down
  for (int k = 0; k < 13; ++k) f.step(0.0f, 0.0f);
  const RefSample s = f.step(0.0f, 0.0f);
  EXPECT_NEAR(1e-6, 0.0, s.v_m_s);
  EXPECT_NEAR(1e-6, 0.0, s.omega_rad_s);
}

// Constant v, omega: the pose runs on a circle of radius v/omega, with v_r = ds/dt.
void test_pose_on_a_circle() {
  DriveReference f(kLim, kDt);
  const DriveConfigQ c(kLim, kDtUs);
  DriveReferenceQ q;
  RefSample s{};
  RefSampleQ sq{};
  for (int k = 0; k < 40; ++k) {  // ramp (8 ticks), then 1.6 s at the target
    s = f.step(0.4f, 1.0f);
    sq = q.step(c, drive_v_q12(400), drive_omega_q11(1000));
  }
  const double R = 0.4;
  const double cx = s.x_m - R * sin(s.phi_rad), cy = s.y_m + R * cos(s.phi_rad);
  double worst = 0, worst_q = 0, len = 0;
  double px = s.x_m, py = s.y_m;
  for (int k = 0; k < 126; ++k) {  // one full turn (2 pi / (omega dt))
    s = f.step(0.4f, 1.0f);
    sq = q.step(c, drive_v_q12(400), drive_omega_q11(1000));
    worst = fmax(worst, fabs(hypot(s.x_m - cx, s.y_m - cy) - R));
    worst_q = fmax(worst_q, fabs(hypot(sq.x_q20 / 1048576.0 - cx, sq.y_q20 / 1048576.0 - cy) - R));
    len += hypot(s.x_m - px, s.y_m - py);
    px = s.x_m;
    py = s.y_m;
  }
  printf("circle R = 0.4 m: radius error float %.2e m, fixed %.2e m; chord length per tick %.6f m (v dt = 0.02)\n",
         worst, worst_q, len / 126);
  // the midpoint rule's edges are arc lengths: a polygon of circumradius R (w dt / 2) / sin(w dt / 2),
  // R (1 + (w dt)^2 / 24) = R + 4.2e-5 m here; the centre taken from one sample doubles that
  TEST_ASSERT_TRUE(worst < 1e-4);
  TEST_ASSERT_TRUE(worst_q < 3e-4);
  EXPECT_NEAR(2e-5, 0.02, len / 126);
}

// The fixed step against the float one over 60 s of random commands (the targets the host can
// send: whole mm/s and mrad/s).
void test_fixed_vs_float_random_drive() {
  const DriveConfigQ c(kLim, kDtUs);
  DriveReferenceQ q;
  // the float reference with the fixed one's rounded steps, so that both ramp alike
  DriveReference f(DriveLimits{c.dv_step_q12 / 4096.0f / kDt, c.dw_step_q11 / 2048.0f / kDt}, kDt);
  srand(7);
  int16_t v_mm = 0, w_mrad = 0;
  double worst_p = 0, worst_phi = 0, worst_v = 0, worst_w = 0;
  for (int k = 0; k < 1200; ++k) {
    if (k % 10 == 0) {
      v_mm = static_cast<int16_t>(rand() % 1601 - 600);
      w_mrad = static_cast<int16_t>(rand() % 6001 - 3000);
    }
    const int16_t vq = drive_v_q12(v_mm), wq = drive_omega_q11(w_mrad);
    const RefSample s = f.step(vq / 4096.0f, wq / 2048.0f);
    const RefSampleQ sq = q.step(c, vq, wq);
    worst_p = fmax(worst_p, hypot(s.x_m - sq.x_q20 / 1048576.0, s.y_m - sq.y_q20 / 1048576.0));
    const double phq = static_cast<int32_t>(sq.phi_b32) * (2 * kPi / 4294967296.0);
    worst_phi = fmax(worst_phi, fabs(wrap(s.phi_rad - phq)));
    worst_v = fmax(worst_v, fabs(s.v_m_s - sq.v_q12 / 4096.0));
    worst_w = fmax(worst_w, fabs(s.omega_rad_s - sq.omega_q11 / 2048.0));
  }
  printf("60 s random drive, fixed vs float: position %.2e m, heading %.2e rad, v %.2e m/s, omega %.2e rad/s\n",
         worst_p, worst_phi, worst_v, worst_w);
  TEST_ASSERT_TRUE(worst_v < 1e-6);
  TEST_ASSERT_TRUE(worst_w < 1e-6);
  TEST_ASSERT_TRUE(worst_p < 2e-3);
  TEST_ASSERT_TRUE(worst_phi < 1e-3);
}

void test_latch_timeout() {
  DriveLatch l;
  const uint32_t t0 = 4294900000UL;  // just before the microsecond clock wraps
  l.received(300, -500, t0);
  TEST_ASSERT_EQUAL_INT16(300, l.v_mm_s(static_cast<uint32_t>(t0 + 499999UL), 500000));
  TEST_ASSERT_EQUAL_INT16(-500, l.omega_mrad_s(static_cast<uint32_t>(t0 + 499999UL), 500000));
  TEST_ASSERT_EQUAL_INT16(0, l.v_mm_s(static_cast<uint32_t>(t0 + 500000UL), 500000));  // wrapped past 2^32
  TEST_ASSERT_EQUAL_INT16(0, l.omega_mrad_s(static_cast<uint32_t>(t0 + 500000UL), 500000));
  l.received(100, 0, 1000);
  TEST_ASSERT_EQUAL_INT16(100, l.v_mm_s(2000, 500000));
}

int main() {
  UNITY_BEGIN();
  RUN_TEST(test_targets_in_controller_formats);
  RUN_TEST(test_config);
  RUN_TEST(test_ramps_within_limits);
  RUN_TEST(test_pose_on_a_circle);
  RUN_TEST(test_fixed_vs_float_random_drive);
  RUN_TEST(test_latch_timeout);
  return UNITY_END();
}
