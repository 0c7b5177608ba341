// lib/closedloop's driver: its schedule against the controller and the plant stepped by hand
// (the firmware's order), the plant rows, determinism after reset, and the configuration check.
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <unity.h>

#include <closedloop/driver.h>
#include "../table.h"

void setUp() {}
void tearDown() {}

namespace {

cl::DriverConfig eight(bool fixed) {
  cl::DriverConfig c;
  c.fixed_point = fixed;
  c.ref = ctl::ReferenceSpec{ctl::PathKind::kFigureEight, 0.5f, 0.4f, 0.6f};
  c.t0_s = 3.0;
  return c;
}

}  // namespace

// The float cascade and the plant stepped by hand on the firmware's schedule (the start tick,
// then inner on the counts, outer after it every other tick, the duty ramped per ms over 50 Euler steps) give
// the driver's numbers bit for bit.
void test_driver_follows_the_firmware_schedule() {
  const cl::DriverConfig dc = eight(false);
  cl::Driver drv(dc);
  drv.plant().set_effect(slip::kMotorLag, true, 0.04);
  drv.reset(-0.1, 0.15, 0.4);
  ctl::Controller c(dc.ctl);
  c.reset(0, 0, ctl::Pose{-0.1f, 0.15f, 0.4f});
  slip::Plant p;
  p.set_effect(slip::kMotorLag, true, 0.04);
  p.reset(-0.1, 0.15, 0.4);
  p.set_time(3.0);
  int differ = 0;
  for (int k = 0; k < 400; ++k) {
    const int32_t er = static_cast<int32_t>(floor(p.state().theta_r_rad * tbl::kPpr / (2 * M_PI)));
    const int32_t el = static_cast<int32_t>(floor(p.state().theta_l_rad * tbl::kPpr / (2 * M_PI)));
    // tick 0: the start tick (reset, outer step at t = 0, first command from rest)
    const ctl::InnerOut o = k == 0 ? c.start(er, el, ctl::Pose{-0.1f, 0.15f, 0.4f}, ctl::reference_at(dc.ref, 0.0f))
                                   : c.inner_step(er, el, 0.025f);
    if (k > 0 && k % 2 == 0) c.outer_step(ctl::reference_at(dc.ref, static_cast<float>(k * 0.025)));
    const cl::TickOut& t = drv.step();
    if (t.enc_r != er || t.enc_l != el || t.ctl.pwm_r != o.pwm_r || t.ctl.pwm_l != o.pwm_l ||
        t.plant.x_m != p.state().x_m || t.t_s != 3.0 + 0.025 * k)
      ++differ;
    // the row's span on the clock's grid, in 50 equal steps (<= 0.5 ms), clock re-aligned; the
    // duty of a clamped wheel grows by its slope every millisecond (the firmware's 1 kHz ramp)
    const double span = (3.0 + 0.025 * (k + 1)) - (3.0 + 0.025 * k);
    for (int j = 0; j < 50; ++j) {
      const double ms = fmin(floor(j * (span / 50) * 1e3 + 1e-9), 24.0);
      p.step_duty(fmin(fmax(o.pwm_r + o.pwm_slope_r * ms, -1.0), 1.0),
                  fmin(fmax(o.pwm_l + o.pwm_slope_l * ms, -1.0), 1.0), span / 50);
    }
    p.set_time(3.0 + 0.025 * (k + 1));
  }
  printf("driver vs hand-stepped loop: %d of 400 ticks differ; final x %.6f / %.6f m\n", differ,
         drv.plant().state().x_m, p.state().x_m);
  TEST_ASSERT_EQUAL_INT(0, differ);
  TEST_ASSERT_TRUE(drv.plant().state().theta_r_rad > 50.0);  // it drove (~4 m in 10 s)
}

void test_rows_and_determinism_after_reset() {
  cl::DriverConfig dc = eight(true);
  dc.rows_per_tick = 5;
  dc.actuator = cl::Actuator::kTorque;
  cl::Driver drv(dc);
  slip::PlantState rows[5];
  double first[120];
  for (int pass = 0; pass < 2; ++pass) {
    drv.reset(0.0, 0.0, 0.0);
    for (int k = 0; k < 120; ++k) {
      const cl::TickOut& t = drv.step(rows);
      TEST_ASSERT_EQUAL_INT64(k, t.k);
      TEST_ASSERT_TRUE(t.plant.x_m == rows[0].x_m);  // row 0 is the tick
      for (int j = 0; j < 5; ++j) TEST_ASSERT_TRUE(fabs(3.0 + 0.005 * (5 * k + j) - rows[j].t_s) < 1e-12);
      if (pass == 0) first[k] = t.ctl.tau_cmd_r;
      else if (first[k] != t.ctl.tau_cmd_r) TEST_FAIL_MESSAGE("not the same after reset");
    }
  }
  TEST_ASSERT_TRUE(fabs(first[10]) > 0.01);
}

void test_bad_configuration_is_named() {
  cl::DriverConfig c = eight(true);
  TEST_ASSERT_EQUAL_STRING("", c.check());
  c.inner_s = 0.0;
  TEST_ASSERT_NOT_NULL(strstr(c.check(), "inner period"));
  c = eight(true);
  c.outer_every = 0;
  TEST_ASSERT_NOT_NULL(strstr(c.check(), "outer"));
  c = eight(true);
  c.ref.accel_m_s2 = 0.0f;
  TEST_ASSERT_NOT_NULL(strstr(c.check(), "reference"));
  c = eight(true);
  c.ctl.gains.k_y = 1000.0f;  // does not fit Q8
  TEST_ASSERT_NOT_NULL(strstr(c.check(), "fixed-point"));
  c.fixed_point = false;
  TEST_ASSERT_EQUAL_STRING("", c.check());
}

int main() {
  UNITY_BEGIN();
  RUN_TEST(test_driver_follows_the_firmware_schedule);
  RUN_TEST(test_rows_and_determinism_after_reset);
  RUN_TEST(test_bad_configuration_is_named);
  return UNITY_END();
}
