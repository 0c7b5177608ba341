// Odometry (III.1-III.4) in float and fixed point against exact integration.
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include <unity.h>

#include "../expect_near.h"
#include "../table.h"

#include <control/odometry.h>

using namespace ctl;

namespace {

// The library is configured in float; the exact reference uses the same float-rounded values
// so that it measures the algorithm, not the rounding of r and b to float.
const double kR = static_cast<double>(tbl::kWheelR_m), kB = static_cast<double>(tbl::kHalfTrack_m);
const int32_t kPpr = tbl::kPpr;
const OdometryConfig kCfg{static_cast<float>(kR), static_cast<float>(kB), kPpr};
constexpr OdometryConfigQ kCfgQ{OdometryConfig{tbl::kWheelR_m, tbl::kHalfTrack_m, tbl::kPpr}};
const double kPi = 3.14159265358979323846;


// Exact pose (double) for per-step count increments, assuming constant wheel speeds within a
// step: closed-form circular arc (III.3/III.4 with the sign of III.4 corrected), straight
// segment when the increments are equal. Written independently of the library's sinc form.
struct ExactOdo {
  double x = 0, y = 0, phi = 0;
  void step(int32_t dn_r, int32_t dn_l) {
    const double sr = kR * 2 * kPi * dn_r / kPpr, sl = kR * 2 * kPi * dn_l / kPpr;
    const double dphi = (sr - sl) / (2 * kB);
    if (dn_r == dn_l) {
      x += sr * cos(phi);
      y += sr * sin(phi);
    } else {
      const double rad = kB * (sr + sl) / (sr - sl);  // signed turning radius
      x += rad * (sin(phi + dphi) - sin(phi));
      y += -rad * (cos(phi + dphi) - cos(phi));  // III.4 prints +, which is wrong
    }
    phi += dphi;
  }
};

double wrap(double a) {
  a = fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}
double q20(int32_t v) { return v / 1048576.0; }
double b32(uint32_t a) { return static_cast<int32_t>(a) * (2 * kPi / 4294967296.0); }

// Runs float, fixed and exact odometry on a sequence of increments; returns max errors.
struct Errs {
  double pos_f = 0, phi_f = 0, pos_q = 0, phi_q = 0, pos_fq = 0;
};
template <typename Gen>
Errs run(Gen gen, int steps, int32_t start_r = 0, int32_t start_l = 0) {
  Odometry of(kCfg);
  OdometryQ oq(kCfgQ);
  of.reset(start_r, start_l, Pose{0, 0, 0});
  oq.reset(start_r, start_l, PoseQ{0, 0, 0});
  ExactOdo ex;
  uint32_t er = static_cast<uint32_t>(start_r), el = static_cast<uint32_t>(start_l);
  Errs e;
  for (int k = 0; k < steps; ++k) {
    int32_t dr, dl;
    gen(k, &dr, &dl);
    er += static_cast<uint32_t>(dr);
    el += static_cast<uint32_t>(dl);
    TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kOk),
                      static_cast<int>(of.update(static_cast<int32_t>(er), static_cast<int32_t>(el), 0.025f)));
    TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kOk),
                      static_cast<int>(oq.update(static_cast<int32_t>(er), static_cast<int32_t>(el), 25000)));
    ex.step(dr, dl);
    const double pf = hypot(of.pose().x_m - ex.x, of.pose().y_m - ex.y);
    const double pq = hypot(q20(oq.pose().x_q20) - ex.x, q20(oq.pose().y_q20) - ex.y);
    const double pfq = hypot(q20(oq.pose().x_q20) - of.pose().x_m, q20(oq.pose().y_q20) - of.pose().y_m);
    e.pos_f = fmax(e.pos_f, pf);
    e.pos_q = fmax(e.pos_q, pq);
    e.pos_fq = fmax(e.pos_fq, pfq);
    e.phi_f = fmax(e.phi_f, fabs(wrap(of.pose().phi_rad - ex.phi)));
    e.phi_q = fmax(e.phi_q, fabs(wrap(b32(oq.pose().phi_b32) - ex.phi)));
  }
  return e;
}

}  // namespace

void setUp() {}
void tearDown() {}

void test_straight_line_limit_is_exact_and_finite() {
  // v_r = v_l: the thesis's III.3 divides by zero; ours must give x = n ds, y = 0 exactly.
  Errs e = run([](int, int32_t* r, int32_t* l) { *r = 200; *l = 200; }, 4000);
  Odometry of(kCfg);
  for (int k = 1; k <= 4000; ++k) of.update(200 * k, 200 * k, 0.025f);
  const double expect = 4000 * 200 * kR * 2 * kPi / kPpr;  // 98.8 m
  CHECK_NEAR(expect, of.pose().x_m, 2e-4 * expect, "float x");
  TEST_ASSERT_EQUAL_FLOAT(0.0f, of.pose().y_m);
  TEST_ASSERT_EQUAL_FLOAT(0.0f, of.pose().phi_rad);
  CHECK_NEAR(0, e.pos_q, 2e-6 * expect, "fixed position error on a 98.8 m line");
  TEST_ASSERT_EQUAL_UINT32(0, OdometryQ(kCfgQ).pose().phi_b32);
  // Nearly straight: one count of difference every step (huge radius) stays finite and exact.
  Errs e2 = run([](int k, int32_t* r, int32_t* l) { *r = 150 + (k & 1); *l = 150; }, 2000);
  CHECK_NEAR(0, e2.pos_f, 2e-4, "float, nearly straight");
  // Fixed point: the Q15 sine/cosine is within 3.5e-5 of the truth, so a heading held at one
  // angle can bias the position by up to 3.5e-5 x path length (37 m here -> 1.3 mm).
  const double path2 = 2000 * 150.5 * kR * 2 * kPi / kPpr;
  CHECK_NEAR(0, e2.pos_q, 3.5e-5 * path2, "fixed, nearly straight");
}

void test_arc_matches_circle() {
  // Constant increments: o moves on a circle of radius R = b (n_r + n_l) / (n_r - n_l).
  Errs e = run([](int, int32_t* r, int32_t* l) { *r = 120; *l = 60; }, 2000);
  CHECK_NEAR(0, e.pos_f, 5e-4, "float arc position");
  CHECK_NEAR(0, e.phi_f, 1e-4, "float arc heading (float accumulation)");
  CHECK_NEAR(0, e.pos_q, 2e-5, "fixed arc position");
  CHECK_NEAR(0, e.phi_q, 1e-6, "fixed arc heading");
  // And the closed form after a known number of steps: centre at (0, R).
  Odometry of(kCfg);
  const int n = 37;
  for (int k = 1; k <= n; ++k) of.update(120 * k, 60 * k, 0.025f);
  const double rad = kB * 180.0 / 60.0, phi = n * (kR * 2 * kPi * 60 / kPpr) / (2 * kB);
  CHECK_NEAR(rad * sin(phi), of.pose().x_m, 1e-5, "circle x");
  CHECK_NEAR(rad * (1 - cos(phi)), of.pose().y_m, 1e-5, "circle y (sign of III.4 corrected)");
  TEST_ASSERT_TRUE(of.pose().y_m > 0.0f);  // right wheel faster -> turns left -> y > 0
}

void test_spin_in_place() {
  Errs e = run([](int, int32_t* r, int32_t* l) { *r = 250; *l = -250; }, 3000);
  CHECK_NEAR(0, e.pos_f, 1e-5, "float spin drift");
  CHECK_NEAR(0, e.pos_q, 1e-5, "fixed spin drift");
  CHECK_NEAR(0, e.phi_f, 1e-3, "float spin heading");
  CHECK_NEAR(0, e.phi_q, 1e-6, "fixed spin heading");
}

void test_random_profiles() {
  srand(12345);
  for (int trial = 0; trial < 5; ++trial) {
    // Smooth random wheel speeds (rad/s) sampled into encoder counts by truncation.
    const double a1 = (rand() % 2000) / 100.0 - 10, a2 = (rand() % 2000) / 100.0 - 10;
    const double f1 = 0.1 + (rand() % 100) / 100.0, f2 = 0.1 + (rand() % 100) / 100.0;
    double th_r = 0, th_l = 0;
    int32_t last_r = 0, last_l = 0;
    Errs e = run(
        [&](int k, int32_t* r, int32_t* l) {
          const double t = k * 0.025;
          th_r += 0.025 * (a1 + 20 * sin(f1 * t));
          th_l += 0.025 * (a2 + 20 * cos(f2 * t));
          const int32_t nr = static_cast<int32_t>(floor(th_r * kPpr / (2 * kPi)));
          const int32_t nl = static_cast<int32_t>(floor(th_l * kPpr / (2 * kPi)));
          *r = nr - last_r;
          *l = nl - last_l;
          last_r = nr;
          last_l = nl;
        },
        4000);  // 100 s
    CHECK_NEAR(0, e.pos_f, 2e-3, "float random-profile position");
    CHECK_NEAR(0, e.phi_f, 2e-4, "float random-profile heading");
    CHECK_NEAR(0, e.pos_q, 1e-4, "fixed random-profile position");
    CHECK_NEAR(0, e.phi_q, 1e-6, "fixed random-profile heading");
  }
}

void test_count_wraparound() {
  auto gen = [](int k, int32_t* r, int32_t* l) { *r = 100 + k % 7; *l = 90 - k % 5; };
  // Start just below INT32_MAX (right) and just above INT32_MIN going backwards (left).
  Odometry a(kCfg), b(kCfg);
  OdometryQ aq(kCfgQ), bq(kCfgQ);
  const int32_t s_r = INT32_MAX - 5000, s_l = INT32_MIN + 10;
  a.reset(0, 0, Pose{0, 0, 0});
  b.reset(s_r, s_l, Pose{0, 0, 0});
  aq.reset(0, 0, PoseQ{0, 0, 0});
  bq.reset(s_r, s_l, PoseQ{0, 0, 0});
  uint32_t ar = 0, al = 0, br = static_cast<uint32_t>(s_r), bl = static_cast<uint32_t>(s_l);
  for (int k = 0; k < 200; ++k) {
    int32_t dr, dl;
    gen(k, &dr, &dl);
    dl = -dl;
    ar += dr; al += dl; br += dr; bl += dl;
    a.update(static_cast<int32_t>(ar), static_cast<int32_t>(al), 0.025f);
    b.update(static_cast<int32_t>(br), static_cast<int32_t>(bl), 0.025f);
    aq.update(static_cast<int32_t>(ar), static_cast<int32_t>(al), 25000);
    TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kOk),
                      static_cast<int>(bq.update(static_cast<int32_t>(br), static_cast<int32_t>(bl), 25000)));
  }
  TEST_ASSERT_TRUE(static_cast<int32_t>(br) < 0);  // really wrapped
  TEST_ASSERT_EQUAL_FLOAT(a.pose().x_m, b.pose().x_m);
  TEST_ASSERT_EQUAL_FLOAT(a.pose().phi_rad, b.pose().phi_rad);
  TEST_ASSERT_EQUAL_FLOAT(a.omega_r_rad_s(), b.omega_r_rad_s());
  TEST_ASSERT_EQUAL_INT32(aq.pose().x_q20, bq.pose().x_q20);
  TEST_ASSERT_EQUAL_INT32(aq.pose().y_q20, bq.pose().y_q20);
  TEST_ASSERT_EQUAL_UINT32(aq.pose().phi_b32, bq.pose().phi_b32);
}

void test_wheel_speed_III_1() {
  Odometry of(kCfg);
  OdometryQ oq(kCfgQ);
  of.update(100, -37, 0.025f);
  oq.update(100, -37, 25000);
  const double wr = 2 * kPi * 100 / (kPpr * 0.025), wl = 2 * kPi * -37 / (kPpr * 0.025);
  CHECK_NEAR(wr, of.omega_r_rad_s(), 1e-5, "float w_r");
  CHECK_NEAR(wl, of.omega_l_rad_s(), 1e-5, "float w_l");
  CHECK_NEAR(kR * (wr + wl) / 2, of.v_m_s(), 1e-6, "float v");
  CHECK_NEAR(kR * (wr - wl) / (2 * kB), of.omega_rad_s(), 1e-6, "float omega");
  CHECK_NEAR(wr, oq.omega_r_q8() / 256.0, 1.0 / 256, "fixed w_r");
  CHECK_NEAR(wl, oq.omega_l_q8() / 256.0, 1.0 / 256, "fixed w_l");
  CHECK_NEAR(kR * (wr + wl) / 2, oq.v_q12() / 4096.0, 2.0 / 4096, "fixed v");
  CHECK_NEAR(kR * (wr - wl) / (2 * kB), oq.omega_q11() / 2048.0, 2.0 / 2048, "fixed omega");
  // Another dt (50 ms) recomputes the cached reciprocal.
  oq.update(200, -74, 50000);
  CHECK_NEAR(2 * kPi * 100 / (kPpr * 0.05), oq.omega_r_q8() / 256.0, 1.0 / 256, "fixed w_r, 50 ms");
  // 10 ms takes the 32-bit path (the per-count rate no longer fits 16 bits).
  oq.update(240, -84, 10000);
  CHECK_NEAR(2 * kPi * 40 / (kPpr * 0.01), oq.omega_r_q8() / 256.0, 1.0 / 256, "fixed w_r, 10 ms");
  CHECK_NEAR(2 * kPi * -10 / (kPpr * 0.01), oq.omega_l_q8() / 256.0, 1.0 / 256, "fixed w_l, 10 ms");
}

// dt measured in microseconds changes every step in the firmware: within +-63 us of the last
// divided dt the rate per count is updated to first order (no division). Wheel speeds must
// stay within the same 1/256 rad/s of the exact value as with the division, for dt around
// the whole fast range (13.6 to 32 ms) and beyond (where the division runs again).
void test_wheel_speed_with_dt_jitter() {
  srand(7);
  const uint32_t centres[] = {13600, 20000, 25000, 32000};
  double worst = 0;
  for (uint32_t c : centres) {
    OdometryQ oq(kCfgQ);
    int32_t er = 0, el = 0;
    for (int k = 0; k < 4000; ++k) {
      const int32_t jit = (k % 50 == 49) ? 400 : 63;  // occasionally beyond the linear window
      const uint32_t dt = static_cast<uint32_t>(static_cast<int32_t>(c) + rand() % (2 * jit + 1) - jit);
      const int32_t dr = rand() % 541 - 270, dl = rand() % 541 - 270;
      er += dr;
      el += dl;
      oq.update_deferred(er, el, dt);
      const double wr = 2 * kPi * dr / (kPpr * (dt * 1e-6)), wl = 2 * kPi * dl / (kPpr * (dt * 1e-6));
      worst = fmax(worst, fmax(fabs(wr - oq.omega_r_q8() / 256.0), fabs(wl - oq.omega_l_q8() / 256.0)));
      if (k % 2) (void)oq.pose();  // as the outer step does
    }
  }
  printf("wheel speeds with dt jitter: max |fixed - exact| %.2e rad/s (bound 1/256 = 3.9e-3)\n", worst);
  TEST_ASSERT_TRUE(worst <= 1.0 / 256);
}

namespace ctl {
// The private rate state (the friend declared in odometry.h; bench/control_avr has its own).
struct OdometryQProbe {
  static void divide(OdometryQ& o, uint32_t dt_us) { o.set_dt(dt_us); }
  static bool equal(const OdometryQ& o, const RateQ& r) {
    return o.div_.dt_us == r.dt_us && o.div_.per_count_q11 == r.per_count_q11 && o.div_.div_q10 == r.div_q10 &&
           o.div_.slope_q12 == r.slope_q12 && o.rate_q10_ == r.div_q10;
  }
};
}  // namespace ctl

// The configuration's precomputed rate (OdometryConfigQ::rate_for, plain C) is the state the
// division leaves, for every dt class (32-bit rate below 13.5 ms, 16-bit above, no slope from
// 64000 units of Q10, 24-bit divisors); a reset from rate_for(25000) then makes a first update at
// 25 ms +- 63 us give exactly the wheel speeds of a controller that divided at 25 ms before.
void test_precomputed_rate_is_the_division() {
  OdometryQ o(kCfgQ);
  uint32_t x = 3;
  for (uint32_t k = 0; k < 200000; ++k) {
    x = x * 1103515245u + 12345u;
    const uint32_t dt = k < 40000 ? 1 + k : 1 + (x >> (k % 24));
    OdometryQProbe::divide(o, dt);
    if (!OdometryQProbe::equal(o, kCfgQ.rate_for(dt))) {
      printf("rate_for(%u) differs from the division\n", static_cast<unsigned>(dt));
      TEST_FAIL();
    }
  }
  TEST_ASSERT_EQUAL_UINT32(0, kCfgQ.rate_for(0).per_count_q11);
  static_assert(kCfgQ.rate_for(25000).dt_us == 25000 && kCfgQ.rate_for(25000).slope_q12 != 0,
                "rate_for is a constant expression");
  srand(13);
  for (int k = 0; k < 2000; ++k) {
    const int32_t e0r = rand() - RAND_MAX / 2, e0l = rand() - RAND_MAX / 2;
    const int32_t dr = rand() % 541 - 270, dl = rand() % 541 - 270;
    const uint32_t dt = 25000 + rand() % 127 - 63;
    OdometryQ a(kCfgQ), b(kCfgQ);
    a.reset(e0r, e0l, PoseQ{0, 0, 0}, kCfgQ.rate_for(25000));
    b.reset(e0r, e0l, PoseQ{0, 0, 0});
    b.update_deferred(e0r, e0l, 25000);  // divides at 25 ms
    a.update_deferred(e0r + dr, e0l + dl, dt);
    b.update_deferred(e0r + dr, e0l + dl, dt);
    TEST_ASSERT_EQUAL_INT16(b.omega_r_q8(), a.omega_r_q8());
    TEST_ASSERT_EQUAL_INT16(b.omega_l_q8(), a.omega_l_q8());
    TEST_ASSERT_EQUAL_INT16(b.v_q12(), a.v_q12());
    TEST_ASSERT_EQUAL_INT16(b.omega_q11(), a.omega_q11());
  }
}

// Deferring the arcs (update_deferred, integrated when the pose is read) gives exactly the
// pose of integrating at every update, whatever the reading pattern.
void test_deferred_pose_is_identical() {
  srand(11);
  OdometryQ a(kCfgQ), b(kCfgQ);
  int32_t er = 0, el = 0;
  for (int k = 0; k < 5000; ++k) {
    er += rand() % 541 - 270;
    el += rand() % 541 - 270;
    const uint32_t dt = 25000 + rand() % 41 - 20;
    a.update(er, el, dt);
    b.update_deferred(er, el, dt);
    TEST_ASSERT_TRUE(b.pending() <= OdometryQ::kMaxPending);
    TEST_ASSERT_EQUAL_INT16(a.omega_r_q8(), b.omega_r_q8());
    TEST_ASSERT_EQUAL_INT16(a.v_q12(), b.v_q12());
    if (rand() % 3 == 0) {  // read at irregular times (also not at all for several steps)
      TEST_ASSERT_EQUAL_INT32(a.pose().x_q20, b.pose().x_q20);
      TEST_ASSERT_EQUAL_INT32(a.pose().y_q20, b.pose().y_q20);
      TEST_ASSERT_EQUAL_UINT32(a.pose().phi_b32, b.pose().phi_b32);
      TEST_ASSERT_EQUAL_UINT8(0, b.pending());
    }
  }
  TEST_ASSERT_EQUAL_INT32(a.pose().x_q20, b.pose().x_q20);
  TEST_ASSERT_TRUE(a.pose().x_q20 != 0 || a.pose().y_q20 != 0);
}

void test_bad_input_is_reported_and_finite() {
  Odometry of(kCfg);
  OdometryQ oq(kCfgQ);
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kBadDt), static_cast<int>(of.update(10, 10, 0.0f)));
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kBadDt), static_cast<int>(of.update(20, 20, NAN)));
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kBadDt), static_cast<int>(oq.update(10, 10, 0)));
  TEST_ASSERT_EQUAL_FLOAT(0.0f, of.omega_r_rad_s());
  TEST_ASSERT_TRUE(of.pose().x_m > 0.0f);  // the pose still integrates the counts
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kCountJump),
                    static_cast<int>(of.update(10 + 100000, 20, 0.025f)));
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kCountJump),
                    static_cast<int>(oq.update(10 + 100000, 20, 25000)));
  TEST_ASSERT_TRUE(isfinite(of.pose().x_m) && isfinite(of.pose().phi_rad));
  TEST_ASSERT_EQUAL_INT16(INT16_MAX, oq.omega_r_q8());  // saturated, not wrapped
  Odometry bad(OdometryConfig{0.0f, tbl::kHalfTrack_m, tbl::kPpr});
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kBadConfig), static_cast<int>(bad.update(1, 1, 0.025f)));
  constexpr OdometryConfigQ badq{OdometryConfig{tbl::kWheelR_m, -1.0f, tbl::kPpr}};
  OdometryQ bq(badq);
  TEST_ASSERT_EQUAL(static_cast<int>(OdoStatus::kBadConfig), static_cast<int>(bq.update(1, 1, 25000)));
}

void test_fixed_vs_float_ten_minutes() {
  // 10 minutes at 25 ms (24,000 steps) of random driving up to full motor speed
  // (the no-load speed, about 270 counts per step) including spins; stated bounds are checked and printed.
  srand(777);
  int32_t vr = 0, vl = 0;
  Errs e = run(
      [&](int k, int32_t* r, int32_t* l) {
        if (k % 80 == 0) {  // new wheel-speed targets every 2 s
          vr = rand() % 541 - 270;
          vl = rand() % 541 - 270;
        }
        *r = vr;
        *l = vl;
      },
      24000);
  printf("10-min run: max |pos| error vs exact: float %.3g m, fixed %.3g m; fixed-float %.3g m;"
         " heading error float %.3g rad, fixed %.3g rad\n",
         e.pos_f, e.pos_q, e.pos_fq, e.phi_f, e.phi_q);
  CHECK_NEAR(0, e.pos_q, 1e-3, "fixed 10-min position bound (1 mm)");
  CHECK_NEAR(0, e.phi_q, 1e-5, "fixed 10-min heading bound");
  CHECK_NEAR(0, e.pos_fq, 2e-2, "fixed vs float 10-min bound (2 cm)");
}

int main() {
  UNITY_BEGIN();
  RUN_TEST(test_straight_line_limit_is_exact_and_finite);
  RUN_TEST(test_arc_matches_circle);
  RUN_TEST(test_spin_in_place);
  RUN_TEST(test_random_profiles);
  RUN_TEST(test_count_wraparound);
  RUN_TEST(test_wheel_speed_III_1);
  RUN_TEST(test_wheel_speed_with_dt_jitter);
  RUN_TEST(test_precomputed_rate_is_the_division);
  RUN_TEST(test_deferred_pose_is_identical);
  RUN_TEST(test_bad_input_is_reported_and_finite);
  RUN_TEST(test_fixed_vs_float_ten_minutes);
  return UNITY_END();
}
