// Each optional effect changes the motion the way its equation says (README, "Effects"), and an
// effect switched on with its default (neutral) parameters changes nothing.
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unity.h>

#include "../expect_near.h"

#include <slipmodel/effects.h>
#include <slipmodel/keys.h>
#include <slipmodel/motor.h>
#include <slipmodel/plant.h>
#include <slipmodel/rolling.h>
#include <slipmodel/traction.h>

using namespace slip;


static const double kDt = 5e-4;

void setUp(void) {}
void tearDown(void) {}

static int run(Plant& pl, int mode, double in_r, double in_l, double T) {
  int slip_steps = 0;
  const long n = lround(T / kDt);
  for (long k = 0; k < n; ++k) {
    if (mode == 0) pl.step_torque(in_r, in_l, kDt);
    else pl.step_duty(in_r, in_l, kDt);
    slip_steps += pl.state().slipping_r + pl.state().slipping_l;
  }
  return slip_steps;
}

static void test_vocabulary_matches_run_format(void) {
  // Names and parameter names exactly as shared/spec/run-format.md lists them.
  const char* expected[] = {"friction_coefficient mu_s mu_k", "wheel_radius r_eff",
                            "track_width b_eff", "motor_back_emf ke_ratio",
                            "driver_voltage_drop volts", "actuation_delay delay_s",
                            "motor_lag tau_s", "axle_viscous c", "axle_coulomb torque",
                            "caster_drag mu", "load_transfer h", "stribeck mu_k0 v_s",
                            "deadband volts", "motor_gain_asymmetry ratio", "floor_slope rad"};
  TEST_ASSERT_EQUAL_INT(15, kEffectCount);
  for (int i = 0; i < kEffectCount; ++i) {
    const EffectInfo& e = effect_info(i);
    char buf[96];
    snprintf(buf, sizeof(buf), "%s %s%s%s", e.name, e.param_names[0], e.param_count > 1 ? " " : "",
             e.param_count > 1 ? e.param_names[1] : "");
    TEST_ASSERT_EQUAL_STRING(expected[i], buf);
    TEST_ASSERT_EQUAL_INT(i, effect_id(e.name));
  }
  TEST_ASSERT_EQUAL_INT(-1, effect_id("no_such_effect"));
  TEST_ASSERT_EQUAL_INT(-1, effect_param_index(kStribeck, "v"));
  Plant pl;
  for (int i = 0; i < kEffectCount; ++i) TEST_ASSERT_FALSE(pl.effects().enabled[i]);
}

static void test_defaults_are_neutral(void) {
  for (int id = 0; id < kEffectCount; ++id) {
    if (id == kLoadTransfer) continue;  // its default is Table II.2's h, not neutral
    for (int mode = 0; mode < 2; ++mode) {
      Plant ref, fx;
      const EffectInfo& e = effect_info(id);
      fx.set_effect(static_cast<EffectId>(id), true, e.defaults[0], e.defaults[1]);
      const double a = mode == 0 ? 0.2 : 0.6, b = mode == 0 ? 0.05 : 0.3;
      run(ref, mode, a, b, 1.0);
      run(fx, mode, a, b, 1.0);
      TEST_ASSERT_EQUAL_MESSAGE(0, memcmp(&ref.state().x_m, &fx.state().x_m, sizeof(double)), e.name);
      TEST_ASSERT_EQUAL_MESSAGE(0, memcmp(&ref.state().phi_rad, &fx.state().phi_rad, sizeof(double)), e.name);
      TEST_ASSERT_EQUAL_MESSAGE(0, memcmp(&ref.state().dtheta_l_rad_s, &fx.state().dtheta_l_rad_s, sizeof(double)), e.name);
    }
  }
}

static void test_friction_coefficient(void) {
  Plant pl;
  pl.set_effect(kFrictionCoefficient, true, 0.5, 0.45);
  RobotParams hi;
  hi.mu_s = 0.5;
  EXPECT_NEAR(1e-12, tau_max(hi, normal_forces(hi).N_r), pl.tau_max_nm(0));
  TEST_ASSERT_EQUAL_INT(0, run(pl, 0, 0.1, 0.1, 1.0));  // 0.1 N m no longer slips
  Plant s;
  s.set_effect(kFrictionCoefficient, true, 0.5, 0.45);
  run(s, 0, 0.4, 0.4, 0.1);
  const double v0 = s.state().v_m_s;
  run(s, 0, 0.4, 0.4, 1.0);
  const RobotParams p;
  EXPECT_NEAR(1e-9, 2.0 * 0.45 * normal_forces(p).N_r / p.m_t(), s.state().v_m_s - v0);
  // mu_k above mu_s is used as mu_s: the wheels slip steadily, without stick/slip chatter.
  Plant hi_k;
  hi_k.set_effect(kFrictionCoefficient, true, table::mu_s, 0.3);
  int transitions = 0;
  bool prev = false;
  for (int k = 0; k < 2000; ++k) {
    hi_k.step_torque(0.1, 0.1, kDt);  // needs between mu_s N and 0.3 N
    transitions += hi_k.state().slipping_r != prev;
    prev = hi_k.state().slipping_r;
  }
  TEST_ASSERT_EQUAL_INT(1, transitions);
}

static void test_wheel_radius(void) {
  Plant pl;
  pl.set_effect(kWheelRadius, true, 0.04);
  run(pl, 0, 0.05, 0.05, 1.0);
  RobotParams p;
  p.r = 0.04;
  EXPECT_NEAR(1e-9, 2 * 0.05 / (0.04 * (p.m_t() + 2 * p.I_wy / (0.04 * 0.04))), pl.state().v_m_s);
  EXPECT_NEAR(1e-9, pl.state().v_m_s, 0.04 * pl.state().dtheta_r_rad_s);
}

static void test_track_width(void) {
  Plant pl;
  pl.set_effect(kTrackWidth, true, 0.12);
  run(pl, 0, 0.03, 0.01, 0.5);
  const PlantState& s = pl.state();
  TEST_ASSERT_FALSE(s.slipping_r || s.slipping_l);
  EXPECT_NEAR(1e-9, table::r * (s.dtheta_r_rad_s - s.dtheta_l_rad_s) / (2 * 0.12), s.omega_rad_s);
}

static double steady_wheel_speed(EffectId id, double p0, double u) {
  Plant pl;
  pl.set_effect(id, true, p0);
  run(pl, 1, u, u, 6.0);
  return pl.state().dtheta_r_rad_s;
}

static void test_motor_back_emf(void) {
  // No-load speed drops to u no_load / ke_ratio; in torque mode the effect does nothing.
  EXPECT_NEAR(0.01, 0.3 * table::no_load_rad_s / 1.2, steady_wheel_speed(kMotorBackEmf, 1.2, 0.3));
  Plant a, b;
  b.set_effect(kMotorBackEmf, true, 1.2);
  run(a, 0, 0.05, 0.05, 0.5);
  run(b, 0, 0.05, 0.05, 0.5);
  EXPECT_NEAR(0.0, a.state().x_m, b.state().x_m);
}

static void test_driver_voltage_drop(void) {
  EXPECT_NEAR(0.01, 0.3 * table::no_load_rad_s * (table::supply_v - 2.0) / table::supply_v, steady_wheel_speed(kDriverVoltageDrop, 2.0, 0.3));
}

// The datasheet-form motor of a fitted back-EMF ratio and voltage drop: its duty for a torque
// gives exactly that torque on the imperfect motor (the firmware's map after SetModel).
static void test_motor_as_driven_inverts_the_imperfect_motor(void) {
  const MotorParams m = datasheet_motor();
  MotorImperfections x;
  x.ke_ratio = 1.15;
  x.drop_v = 1.4;
  const MotorParams e = motor_as_driven(m, x);
  int checked = 0;
  for (double tau = -0.3; tau <= 0.3; tau += 0.05) {
    for (double w = -20.0; w <= 20.0; w += 5.0) {
      const double u = motor_duty_for_torque(e, tau, w);
      if (fabs(u) >= 1.0) continue;
      EXPECT_NEAR(1e-12, tau, motor_torque_nm(m, u, w, x));
      ++checked;
    }
  }
  TEST_ASSERT_TRUE(checked > 50);
  // the datasheet map is off by the same amount the effects make (so the test can fail)
  EXPECT_NEAR(1e-12, m.supply_v, e.supply_v);
  TEST_ASSERT_TRUE(fabs(motor_torque_nm(m, motor_duty_for_torque(m, 0.2, 15.0), 15.0, x) - 0.2) > 0.02);
  // neutral imperfections: the datasheet motor; unusable ones (k <= 0, D >= S): unchanged
  EXPECT_NEAR(0.0, m.no_load_rad_s, motor_as_driven(m, MotorImperfections()).no_load_rad_s);
  x.drop_v = m.supply_v;
  EXPECT_NEAR(0.0, m.stall_nm, motor_as_driven(m, x).stall_nm);
}

static void test_deadband(void) {
  Plant pl;
  pl.set_effect(kDeadband, true, 1.0);
  run(pl, 1, 0.05, 0.05, 1.0);  // 0.6 V < 1 V: no torque
  EXPECT_NEAR(0.0, 0.0, pl.state().x_m);
  EXPECT_NEAR(0.01, (0.3 * table::supply_v - 1.0) / table::supply_v * table::no_load_rad_s, steady_wheel_speed(kDeadband, 1.0, 0.3));
}

static void test_actuation_delay(void) {
  Plant ref, del;
  del.set_effect(kActuationDelay, true, 0.1);
  run(del, 0, 0.05, 0.05, 0.1);
  EXPECT_NEAR(0.0, 0.0, del.state().x_m);  // nothing arrives before 0.1 s
  run(del, 0, 0.05, 0.05, 0.5);
  run(ref, 0, 0.05, 0.05, 0.5);
  EXPECT_NEAR(1e-12, ref.state().x_m, del.state().x_m);  // then the same motion, 0.1 s late
}

// The C ABI re-aligns the clock with set_time() at every input sample (decimal grids such as
// 0.02 s are not sums of binary steps): that rounding must not empty the delay line.
static void test_actuation_delay_survives_clock_realignment(void) {
  Plant free_running, realigned;
  free_running.set_effect(kActuationDelay, true, 0.01);
  realigned.set_effect(kActuationDelay, true, 0.01);
  for (int k = 0; k < 50; ++k) {  // 1 s of 0.02 s input samples, 40 steps each
    for (int i = 0; i < 40; ++i) {
      free_running.step_torque(0.05, 0.05, kDt);
      realigned.step_torque(0.05, 0.05, kDt);
    }
    realigned.set_time((k + 1) * 0.02);
  }
  EXPECT_NEAR(1e-9, free_running.state().x_m, realigned.state().x_m);
  TEST_ASSERT_TRUE(realigned.state().x_m > 0.1);
}

static void test_motor_lag(void) {
  Plant pl;
  pl.set_effect(kMotorLag, true, 0.05);
  run(pl, 0, 0.08, 0.08, 0.05);
  EXPECT_NEAR(1e-9, 0.08 * (1.0 - exp(-1.0)), pl.state().tau_r_nm);  // one time constant
  run(pl, 0, 0.08, 0.08, 0.5);
  EXPECT_NEAR(0.08 * 2e-5, 0.08, pl.state().tau_l_nm);  // exp(-11) = 1.7e-5 left
}

static void test_axle_viscous(void) {
  Plant pl;
  pl.set_effect(kAxleViscous, true, 0.002);
  run(pl, 0, 0.05, 0.05, 12.0);  // terminal speed where tau = c dtheta
  EXPECT_NEAR(0.005 * 25.0, 25.0, pl.state().dtheta_r_rad_s);
}

static void test_axle_coulomb(void) {
  Plant stuck;
  stuck.set_effect(kAxleCoulomb, true, 0.02);
  run(stuck, 0, 0.015, 0.015, 1.0);  // below the friction torque: (almost) no motion
  TEST_ASSERT_TRUE(fabs(stuck.state().x_m) < 1e-3);
  Plant pl;
  pl.set_effect(kAxleCoulomb, true, 0.02);
  run(pl, 0, 0.05, 0.05, 1.0);  // above it: accelerates like 0.03 N m without friction
  const RobotParams p;
  // The friction is regularised over |dtheta| < 2 T dt / I_wy (README); the few steps spent in
  // that band at the start leave a velocity excess of about 2 dt * 2T/(r m_eff) = 3e-4 m/s.
  EXPECT_NEAR(5e-4, 2 * 0.03 / (p.r * rolling_mass_kg(p)), pl.state().v_m_s);
}

static void test_caster_drag(void) {
  Plant pl;
  pl.set_effect(kCasterDrag, true, 0.1);
  run(pl, 0, 0.05, 0.05, 1.0);
  const RobotParams p;
  const double Nc = normal_forces(p).N_c;
  // regularised like axle_coulomb: a few start-up steps in the band give < 5e-4 m/s excess
  EXPECT_NEAR(5e-4, (2 * 0.05 / p.r - 0.1 * Nc) / rolling_mass_kg(p), pl.state().v_m_s);
  Plant still;  // drag alone never moves the robot
  still.set_effect(kCasterDrag, true, 0.1);
  run(still, 0, 0.0, 0.0, 0.5);
  EXPECT_NEAR(0.0, 0.0, still.state().x_m);
}

static void test_load_transfer(void) {
  // Forward acceleration unloads the caster and loads the wheels by m_t a (h + h_s) / (d + e),
  // h_s = 2 I_wy / (m_t r) the wheels' spin-up while they roll (README, "Load transfer and
  // spin-up"), which raises the wheels' traction: a ramp to 0.097 N m (above the static
  // tau_max) then holds without slipping with h = 0.05 m, but slips without the effect.
  const RobotParams p;
  Plant with, without;
  with.set_effect(kLoadTransfer, true, 0.05);
  int slips_with = 0, slips_without = 0;
  for (int k = 1; k <= 2000; ++k) {
    const double tau = 0.097 * (k < 400 ? k / 400.0 : 1.0);
    with.step_torque(tau, tau, kDt);
    without.step_torque(tau, tau, kDt);
    slips_with += with.state().slipping_r;
    slips_without += without.state().slipping_r;
  }
  TEST_ASSERT_EQUAL_INT(0, slips_with);
  TEST_ASSERT_TRUE(slips_without > 0);
  const double a = 2 * 0.097 / (p.r * rolling_mass_kg(p));
  const double h_s = 2 * p.I_wy / (p.m_t() * p.r);
  EXPECT_NEAR(1e-6, normal_forces(p).N_c - p.m_t() * a * (0.05 + h_s) / (p.d + p.e),
              with.state().N_c);
  EXPECT_NEAR(1e-9, p.m_t() * p.g, with.state().N_r + with.state().N_l + with.state().N_c);
}

static double caster_after(Plant& pl, double tau_nm, int steps) {
  for (int k = 0; k < steps; ++k) pl.step_torque(tau_nm, tau_nm, kDt);
  return pl.state().N_c;
}

static void test_load_transfer_spin_up_of_wheels_on_a_body_at_rest(void) {
  // Frictionless floor: the body stays at rest (a_x = 0, so h plays no part) while each wheel
  // spins up at tau / I_wy. The motors' reaction pitches the body nose up: the pitch balance
  // about c gives N_c (d + e) = m_t g d - s I_wy (theta''_r + theta''_l) = m_t g d - 2 s tau,
  // s the share of I_wy whose spin reacts (1 by default; 0 leaves II.29's static N_c).
  const RobotParams p;
  const double tau = 0.05, Nc0 = normal_forces(p).N_c;
  const double shares[] = {1.0, 0.5, 0.0};
  for (double s : shares) {
    Plant pl;
    pl.set_effect(kFrictionCoefficient, true, 0.0, 0.0);
    pl.set_effect(kLoadTransfer, true, 0.05);
    TEST_ASSERT_TRUE(pl.set_spin_share(s));
    const double Nc = caster_after(pl, tau, 10);
    EXPECT_NEAR(1e-12, 0.0, pl.state().v_m_s);
    EXPECT_NEAR(1e-9, 10 * kDt * tau / p.I_wy, pl.state().dtheta_r_rad_s);
    EXPECT_NEAR(1e-9, Nc0 - 2 * s * tau / (p.d + p.e), Nc);
    EXPECT_NEAR(1e-9, p.m_t() * p.g, pl.state().N_r + pl.state().N_l + Nc);
  }
  Plant off;  // the effect off: no pitch balance at all
  off.set_effect(kFrictionCoefficient, true, 0.0, 0.0);
  EXPECT_NEAR(1e-12, Nc0, caster_after(off, tau, 10));
}

static void test_load_transfer_pure_rolling_is_a_height_h_plus_h_s(void) {
  // Rolling straight, theta'' = a / r on both wheels: the spin term I_wy 2 a / r is m_t a h_s,
  // h_s = 2 I_wy / (m_t r). With h = 0 it is the only transfer; forward acceleration unloads the
  // caster, braking (negative torque from rest: backward acceleration) loads it.
  const RobotParams p;
  const double h_s = 2 * p.I_wy / (p.m_t() * p.r), Nc0 = normal_forces(p).N_c;
  const double hs[] = {0.0, 0.03};
  const double taus[] = {0.05, -0.05};
  for (double h : hs) {
    for (double tau : taus) {
      Plant pl;
      pl.set_effect(kLoadTransfer, true, h);
      const double Nc = caster_after(pl, tau, 20);
      TEST_ASSERT_FALSE(pl.state().slipping_r || pl.state().slipping_l);
      const double a = 2 * tau / (p.r * rolling_mass_kg(p));
      EXPECT_NEAR(1e-9, Nc0 - p.m_t() * a * (h + h_s) / (p.d + p.e), Nc);
      if (tau > 0) TEST_ASSERT_TRUE(Nc < Nc0 - 0.01);
      else TEST_ASSERT_TRUE(Nc > Nc0 + 0.01);
    }
  }
}

static void test_spin_share_key(void) {
  // "plant.spin_share": a model setting in [0, 1], outside the vocabulary; kept by clearing the
  // effects and by reset.
  Plant pl;
  double v = -1.0;
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_get(pl, "plant.spin_share", &v));
  EXPECT_NEAR(0.0, 1.0, v);
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_set(pl, "plant.spin_share", 0.25));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "plant.spin_share", 1.5));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "plant.spin_share", -0.1));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "plant.spin_share", NAN));
  TEST_ASSERT_EQUAL_INT(kKeyUnknown, plant_set(pl, "load_transfer.spin_share", 0.5));
  pl.effects().clear();
  pl.reset(0, 0, 0);
  EXPECT_NEAR(0.0, 0.25, pl.spin_share());
}

static void test_stribeck(void) {
  // Friction mu_k0 = mu_s at zero slip speed falling to mu_k: after breakaway at 0.1 N m the
  // body accelerates more than with constant mu_k, and with mu_k once the slip speed is large.
  const RobotParams p;
  Plant ref, st;
  st.set_effect(kStribeck, true, table::mu_s, 0.05);
  run(ref, 0, 0.1, 0.1, 0.3);
  const int st_slips = run(st, 0, 0.1, 0.1, 0.3);
  TEST_ASSERT_EQUAL_INT(2 * 600, st_slips);  // slipping throughout, no re-stick chatter
  TEST_ASSERT_TRUE(st.state().v_m_s > ref.state().v_m_s + 1e-3);
  run(st, 0, 0.1, 0.1, 1.0);
  const double v0 = st.state().v_m_s;
  run(st, 0, 0.1, 0.1, 0.5);
  EXPECT_NEAR(1e-6, 2 * p.mu_k * normal_forces(p).N_r / p.m_t(), (st.state().v_m_s - v0) / 0.5);
}

static void test_motor_gain_asymmetry(void) {
  Plant pl;
  pl.set_effect(kMotorGainAsymmetry, true, 1.2);
  run(pl, 0, 0.04, 0.04, 0.5);
  EXPECT_NEAR(1e-12, 1.2, pl.state().tau_r_nm / pl.state().tau_l_nm);
  TEST_ASSERT_TRUE(pl.state().phi_rad > 0.0);  // stronger right motor turns left
  Plant d;
  d.set_effect(kMotorGainAsymmetry, true, 1.2);
  run(d, 1, 0.1, 0.1, 0.5);
  TEST_ASSERT_TRUE(d.state().phi_rad > 0.0);
  // the asymmetry is one of torque per ampere: the currents are the motor model's, so with equal
  // duties and (at rest) equal speeds both wheels draw the same current
  Plant c;
  c.set_effect(kMotorGainAsymmetry, true, 1.2);
  run(c, 1, 0.3, 0.3, 0.0005);
  EXPECT_NEAR(1e-9, c.current_a(0), c.current_a(1));
  EXPECT_NEAR(1e-9, motor_current_a(c.motor(), motor_torque_nm(c.motor(), 0.3, 0.0)), c.current_a(0));
}

static void test_floor_slope(void) {
  // Uphill along +x: with no torque the robot rolls back with g sin(a) m_t / m_eff.
  const RobotParams p;
  Plant pl;
  pl.set_effect(kFloorSlope, true, 0.05);
  run(pl, 0, 0.0, 0.0, 1.0);
  EXPECT_NEAR(1e-9, -p.m_t() * p.g * sin(0.05) / rolling_mass_kg(p), pl.state().v_m_s);
  EXPECT_NEAR(1e-9, p.m_t() * p.g * cos(0.05), pl.state().N_r + pl.state().N_l + pl.state().N_c);
  // Facing across the slope (+y) the pull is lateral: the wheels hold it sideways (no lateral
  // slip), and its moment about the axle (the centre of mass is d ahead) pivots the robot
  // downhill (heading grows from pi/2 towards pi) before it rolls down (x < 0).
  Plant side;
  side.reset(0, 0, M_PI / 2);
  side.set_effect(kFloorSlope, true, 0.05);
  run(side, 0, 0.0, 0.0, 1.0);
  EXPECT_NEAR(1e-12, 0.0, side.state().w_m_s);
  TEST_ASSERT_TRUE(side.state().phi_rad > M_PI / 2 + 0.3);
  run(side, 0, 0.0, 0.0, 1.0);
  TEST_ASSERT_TRUE(side.state().x_m < -0.05);
}


static void test_string_keys(void) {
  Plant pl;
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_set(pl, "robot.mu_s", 0.5));
  EXPECT_NEAR(0.0, 0.5, pl.robot().mu_s);
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_set(pl, "motor.stall_nm", 1.1));
  EXPECT_NEAR(0.0, 1.1, pl.motor().stall_nm);
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_set(pl, "stribeck.v_s", 0.03));
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_set(pl, "stribeck.enabled", 1.0));
  TEST_ASSERT_TRUE(pl.effects().on(kStribeck));
  double v = 0.0;
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_get(pl, "stribeck.v_s", &v));
  EXPECT_NEAR(0.0, 0.03, v);
  TEST_ASSERT_EQUAL_INT(kKeyOk, plant_get(pl, "robot.I_wy", &v));
  EXPECT_NEAR(0.0, table::I_wy, v);
  // errors change nothing
  TEST_ASSERT_EQUAL_INT(kKeyUnknown, plant_set(pl, "robot.mass", 1.0));
  TEST_ASSERT_EQUAL_INT(kKeyUnknown, plant_set(pl, "stribeck.vs", 1.0));
  TEST_ASSERT_EQUAL_INT(kKeyUnknown, plant_set(pl, ".enabled", 1.0));
  TEST_ASSERT_EQUAL_INT(kKeyUnknown, plant_set(pl, nullptr, 1.0));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "robot.r", 0.0));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "robot.mu_k", NAN));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "wheel_radius.r_eff", -0.01));
  TEST_ASSERT_EQUAL_INT(kKeyBadValue, plant_set(pl, "floor_slope.rad", 2.0));
  EXPECT_NEAR(0.0, table::r, pl.robot().r);
  EXPECT_NEAR(0.0, table::mu_k, pl.robot().mu_k);
  TEST_ASSERT_EQUAL_INT(17, param_key_count());
  TEST_ASSERT_EQUAL_STRING("robot.mu_s", param_key_name(0));
  TEST_ASSERT_EQUAL_STRING("motor.stall_a", param_key_name(16));
  TEST_ASSERT_NULL(param_key_name(17));
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_vocabulary_matches_run_format);
  RUN_TEST(test_defaults_are_neutral);
  RUN_TEST(test_friction_coefficient);
  RUN_TEST(test_wheel_radius);
  RUN_TEST(test_track_width);
  RUN_TEST(test_motor_back_emf);
  RUN_TEST(test_driver_voltage_drop);
  RUN_TEST(test_motor_as_driven_inverts_the_imperfect_motor);
  RUN_TEST(test_deadband);
  RUN_TEST(test_actuation_delay);
  RUN_TEST(test_actuation_delay_survives_clock_realignment);
  RUN_TEST(test_motor_lag);
  RUN_TEST(test_axle_viscous);
  RUN_TEST(test_axle_coulomb);
  RUN_TEST(test_caster_drag);
  RUN_TEST(test_load_transfer);
  RUN_TEST(test_load_transfer_spin_up_of_wheels_on_a_body_at_rest);
  RUN_TEST(test_load_transfer_pure_rolling_is_a_height_h_plus_h_s);
  RUN_TEST(test_spin_share_key);
  RUN_TEST(test_stribeck);
  RUN_TEST(test_motor_gain_asymmetry);
  RUN_TEST(test_floor_slope);
  RUN_TEST(test_string_keys);
  return UNITY_END();
}
