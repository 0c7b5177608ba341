// The C ABI (host_tools/native/control_capi.cpp): self-description, error handling, and a
// closed-loop replay through the ABI that must match the C++ controller bit for bit.
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <unity.h>

#include "../../../host_tools/native/control_capi.cpp"
#include "../test_control_closed_loop/closed_loop_sim.h"

void setUp() {}
void tearDown() {}

void test_describe_and_columns() {
  const char* d = ctl_describe();
  TEST_ASSERT_NOT_NULL(strstr(d, "\"abi\": 1"));
  TEST_ASSERT_NOT_NULL(strstr(d, "\"name\": \"mu_s\""));
  TEST_ASSERT_NOT_NULL(strstr(d, "\"figure_eight\": 2"));
  TEST_ASSERT_NOT_NULL(strstr(d, "{\"name\": \"controller\", \"unit\": \"0 improved, 1 thesis\", \"default\": 0}"));
  TEST_ASSERT_EQUAL_INT(23, ctl_column_count());
  TEST_ASSERT_EQUAL_STRING("pwm_r", ctl_column_name(0));
  TEST_ASSERT_EQUAL_STRING("odo_status", ctl_column_name(20));
  TEST_ASSERT_EQUAL_STRING("pwm_slope_l", ctl_column_name(ctl_column_count() - 1));
  TEST_ASSERT_NULL(ctl_column_name(99));
}

void test_bad_input_is_rejected() {
  void* h = ctl_new(1, 1);
  double v = 0, row[32];
  TEST_ASSERT_EQUAL_INT(-1, ctl_set(h, "nonsense", 1.0));
  TEST_ASSERT_NOT_NULL(strstr(ctl_last_error(h), "unknown key"));
  TEST_ASSERT_EQUAL_INT(-2, ctl_set(h, "k_x", NAN));
  TEST_ASSERT_EQUAL_INT(-2, ctl_set(h, "r", -1.0));
  TEST_ASSERT_EQUAL_INT(-4, ctl_set(h, "k_y", 1000.0));  // does not fit Q8 in fixed point
  TEST_ASSERT_EQUAL_INT(-4, ctl_inner(h, 1, 1, 0.025, row, 32));
  TEST_ASSERT_EQUAL_INT(0, ctl_set(h, "k_y", 6.0));
  TEST_ASSERT_EQUAL_INT(0, ctl_get(h, "k_y", &v));
  TEST_ASSERT_EQUAL_FLOAT(6.0f, static_cast<float>(v));
  TEST_ASSERT_EQUAL_INT(-3, ctl_inner(h, 1, 1, 0.025, row, 5));       // short array
  TEST_ASSERT_EQUAL_INT(-2, ctl_inner(h, 1, 1, 0.0, row, 32));        // bad dt
  TEST_ASSERT_EQUAL_INT(-1, ctl_set_reference(h, 7, 1, 1, 1));
  TEST_ASSERT_EQUAL_INT(-2, ctl_set_reference(h, 1, 0.5, 0.4, 0.0));  // zero radius
  TEST_ASSERT_EQUAL_INT(-2, ctl_reset(h, 0, 0, NAN, 0, 0));
  TEST_ASSERT_EQUAL_INT(-2, ctl_start(h, 0, 0, 0, INFINITY, 0, row, 32));
  TEST_ASSERT_EQUAL_INT(-3, ctl_start(h, 0, 0, 0, 0, 0, row, 5));       // short array
  TEST_ASSERT_EQUAL_INT(-3, ctl_inner(nullptr, 1, 1, 0.025, row, 32));
  TEST_ASSERT_EQUAL_INT(-2, ctl_set(h, "controller", 2.0));
  TEST_ASSERT_EQUAL_INT(-2, ctl_set(h, "controller", 0.5));
  // Selecting a variant loads its default gains.
  TEST_ASSERT_EQUAL_INT(0, ctl_set(h, "controller", 1.0));
  TEST_ASSERT_EQUAL_INT(0, ctl_get(h, "controller", &v));
  TEST_ASSERT_EQUAL_FLOAT(1.0f, static_cast<float>(v));
  TEST_ASSERT_EQUAL_INT(0, ctl_get(h, "k_l", &v));
  TEST_ASSERT_EQUAL_FLOAT(ctl::thesis_gains().k_l, static_cast<float>(v));
  TEST_ASSERT_EQUAL_INT(0, ctl_get(h, "k_il", &v));
  TEST_ASSERT_EQUAL_FLOAT(0.0f, static_cast<float>(v));
  ctl_free(h);
}

// Replays the closed loop through the ABI (float and fixed, both variants) and compares with
// the C++ path.
void test_replay_matches_cpp() {
  for (int run = 0; run < 4; ++run) {
    const int fixed = run % 2;
    const ctl::Variant variant = run < 2 ? ctl::Variant::kImproved : ctl::Variant::kThesis;
    void* h = ctl_new(fixed, 1);
    TEST_ASSERT_EQUAL_INT(0, ctl_set(h, "controller", static_cast<double>(static_cast<uint8_t>(variant))));
    TEST_ASSERT_EQUAL_INT(0, ctl_set_reference(h, 2, 0.5, 0.4, 0.6));
    TEST_ASSERT_EQUAL_INT(0, ctl_reset(h, 0, 0, -0.1, 0.15, 0.4));
    const ctl::ReferenceSpec spec{ctl::PathKind::kFigureEight, 0.5f, 0.4f, 0.6f};
    const ctl::ControlConfig cfg =
        ctl::make_control_config(slip::RobotParams(), slip::MotorParams(), ctl::gains_for(variant), true, variant);
    sim::FloatAdapter fa(cfg);
    sim::FixedAdapter qa(cfg);
    fa.reset(0, 0, -0.1, 0.15, 0.4);
    qa.reset(0, 0, -0.1, 0.15, 0.4);
    slip::Plant plant;
    plant.reset(-0.1, 0.15, 0.4);
    double row[32];
    int max_diff_bits = 0;
    for (int k = 0; k < 400; ++k) {  // 10 s
      const int32_t er = sim::counts(plant.state().theta_r_rad), el = sim::counts(plant.state().theta_l_rad);
      double u_r, u_l;
      if (k == 0) {  // the start tick: reset, outer step at t = 0, first command from rest
        TEST_ASSERT_EQUAL_INT(0, ctl_start(h, er, el, -0.1, 0.15, 0.4, row, 32));
        if (fixed) qa.start(er, el, -0.1, 0.15, 0.4, spec, &u_r, &u_l);
        else fa.start(er, el, -0.1, 0.15, 0.4, spec, &u_r, &u_l);
        TEST_ASSERT_TRUE(fabs(row[0]) > 0.01 && fabs(row[1]) > 0.01);  // it commands at once
      } else {
        TEST_ASSERT_EQUAL_INT(0, ctl_inner(h, er, el, 0.025, row, 32));
        if (fixed) qa.inner(er, el, &u_r, &u_l);
        else fa.inner(er, el, &u_r, &u_l);
      }
      const double s_r = fixed ? qa.slope_r() : fa.slope_r(), s_l = fixed ? qa.slope_l() : fa.slope_l();
      if (row[0] != u_r || row[1] != u_l || row[21] != s_r || row[22] != s_l) ++max_diff_bits;
      if (k > 0 && k % 2 == 0) {
        TEST_ASSERT_EQUAL_INT(0, ctl_outer(h, k * 0.025));
        if (fixed) qa.outer(spec, k * 0.025);
        else fa.outer(spec, k * 0.025);
      }
      for (int j = 0; j < sim::kPlantPerInner; ++j) {  // the duty ramps every millisecond
        const double ms = floor(j * sim::kPlantDt / 1e-3 + 1e-9);
        plant.step_duty(fmin(fmax(row[0] + row[21] * ms, -1.0), 1.0), fmin(fmax(row[1] + row[22] * ms, -1.0), 1.0),
                        sim::kPlantDt);
      }
    }
    TEST_ASSERT_EQUAL_INT(0, max_diff_bits);
    double ref[7];
    TEST_ASSERT_EQUAL_INT(0, ctl_reference(h, 10.0, ref, 7));
    const double err = hypot(plant.state().x_m - ref[0], plant.state().y_m - ref[1]);
    printf("C ABI replay (%s, %s): 10 s on the figure eight, final error %.4f m\n", fixed ? "fixed" : "float",
           run < 2 ? "improved" : "thesis", err);
    // The thesis's P-only loop (no integral, feed-forward m_t and I_t alone) still lags the
    // eight by ~0.12 m after 10 s; the improved loop has converged.
    TEST_ASSERT_TRUE(err < (variant == ctl::Variant::kImproved ? 0.05 : 0.2));
    ctl_free(h);
  }
}

int main() {
  UNITY_BEGIN();
  RUN_TEST(test_describe_and_columns);
  RUN_TEST(test_bad_input_is_rejected);
  RUN_TEST(test_replay_matches_cpp);
  return UNITY_END();
}
