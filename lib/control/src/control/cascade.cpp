#include <control/cascade.h>

#include <math.h>

#include <slipmodel/motor.h>
#include <slipmodel/rolling.h>
#include <slipmodel/traction.h>

namespace ctl {

namespace {
float clampf(float x, float lim) {
  if (!(x == x)) return 0.0f;  // NaN -> 0
  return x > lim ? lim : (x < -lim ? -lim : x);
}
float signf(float x) { return x > 0.0f ? 1.0f : (x < 0.0f ? -1.0f : 0.0f); }
}  // namespace

Gains default_gains() {
  // m_eff = 3.38 kg, I_eff = 0.0366 kg m^2 for Table II.2 (slip::rolling_*).
  return Gains{2.0f, 6.0f, 3.0f, 20.0f, 0.22f, 30.0f, 0.33f};
}

Gains thesis_gains() {
  const slip::RobotParams p;
  const float k_l = 6.0f;
  const float k_a = static_cast<float>(k_l * p.I_t() / p.m_t());  // 0.0455 N m s for Table II.2
  return Gains{2.0f, 6.0f, 3.0f, k_l, k_a, 0.0f, 0.0f};
}

Gains gains_for(Variant v) { return v == Variant::kThesis ? thesis_gains() : default_gains(); }

ControlConfig make_control_config(const slip::RobotParams& robot, const slip::MotorParams& motor,
                                  const Gains& gains, bool clamp_enabled, Variant variant) {
  ControlConfig c;
  c.robot = robot;
  c.motor = motor;
  c.gains = gains;
  c.counts_per_rev = slip::kEncoderPpr;
  c.variant = variant;
  if (variant == Variant::kThesis) {  // II.47: m_t and I_t alone, no coupling terms
    c.m_ff_kg = static_cast<float>(robot.m_t());
    c.I_ff_kgm2 = static_cast<float>(robot.I_t());
    c.mtd_ff_kg_m = 0.0f;
  } else {
    c.m_ff_kg = static_cast<float>(slip::rolling_mass_kg(robot));
    c.I_ff_kgm2 = static_cast<float>(slip::rolling_yaw_inertia_kgm2(robot));
    c.mtd_ff_kg_m = static_cast<float>(robot.m_t() * robot.d);
  }
  c.v_max_m_s = static_cast<float>(robot.r * motor.no_load_rad_s);
  c.omega_max_rad_s = static_cast<float>(robot.r * motor.no_load_rad_s / robot.b);
  // Integrators may hold at most the force/moment of half the stall torque on both wheels.
  c.integ_max_n = static_cast<float>(motor.stall_nm / robot.r);
  c.integ_max_nm = static_cast<float>(motor.stall_nm * robot.b / robot.r);
  c.clamp_enabled = clamp_enabled;
  const double r2 = robot.r * robot.r;
  c.wheel_accel_per_nm = static_cast<float>(2.0 / (r2 * slip::rolling_mass_kg(robot)));
  c.count_rad = static_cast<float>(2.0 * 3.14159265358979323846 / slip::kEncoderPpr);
  // kBackEmfMarginCounts counts per nominal 25 ms tick as back-EMF torque
  c.margin_nm = static_cast<float>(motor.stall_nm / motor.no_load_rad_s * kBackEmfMarginCounts * c.count_rad / 0.025);
  return c;
}

KinematicOut kinematic_law(const Gains& g, const Pose& pose, const RefSample& ref, float v_max,
                           float w_max) {
  KinematicOut k;
  const float dx = ref.x_m - pose.x_m, dy = ref.y_m - pose.y_m;
  const float c = cosf(pose.phi_rad), s = sinf(pose.phi_rad);
  k.e_x_m = c * dx + s * dy;
  k.e_y_m = -s * dx + c * dy;
  k.e_phi_rad = wrap_pi(ref.phi_rad - pose.phi_rad);
  k.v_d_m_s = clampf(ref.v_m_s * cosf(k.e_phi_rad) + g.k_x * k.e_x_m, v_max);
  k.omega_d_rad_s =
      clampf(ref.omega_rad_s + ref.v_m_s * g.k_y * k.e_y_m + g.k_phi * sinf(k.e_phi_rad), w_max);
  return k;
}

WheelPair split_torque(float r, float b, float force_n, float moment_nm) {
  const float m_over_b = moment_nm / b;
  return WheelPair{0.5f * r * (force_n + m_over_b), 0.5f * r * (force_n - m_over_b)};
}

float clamp_torque(float tau, float tau_max, bool* clamped) {
  if (!(tau == tau)) {
    *clamped = true;
    return 0.0f;
  }
  if (!(tau_max >= 0.0f)) tau_max = 0.0f;
  if (tau > tau_max) {
    *clamped = true;
    return tau_max;
  }
  if (tau < -tau_max) {
    *clamped = true;
    return -tau_max;
  }
  *clamped = false;
  return tau;
}

float torque_to_pwm(const slip::MotorParams& m, float tau, float dtheta, bool* saturated) {
  const float u = static_cast<float>(slip::motor_duty_for_torque(m, tau, dtheta));
  // motor_duty_for_torque clamps to [-1, 1]; recompute the unclamped value to flag saturation.
  const float raw = static_cast<float>(tau / m.stall_nm + dtheta / m.no_load_rad_s);
  *saturated = !(raw == raw) || raw >= 1.0f || raw <= -1.0f;
  return u;
}

Controller::Controller(const ControlConfig& cfg)
    : cfg_(cfg),
      odo_cfg_{static_cast<float>(cfg.robot.r), static_cast<float>(cfg.robot.b), cfg.counts_per_rev},
      odo_(odo_cfg_) {
  reset(0, 0, Pose{0, 0, 0});
}

void Controller::reset(int32_t enc_r, int32_t enc_l, const Pose& p) {
  odo_.reset(enc_r, enc_l, p);
  kin_ = KinematicOut{0, 0, 0, 0, 0};
  out_ = InnerOut{0, 0, 0, 0, 0, 0, false, false, false, false, OdoStatus::kOk, 0, 0};
  dv_ff_ = dw_ff_ = 0.0f;
  i_v_ = i_w_ = 0.0f;
  was_r_ = was_l_ = 0;
  update_tau_max();
}

const KinematicOut& Controller::outer_step(const RefSample& ref) {
  kin_ = kinematic_law(cfg_.gains, odo_.pose(), ref, cfg_.v_max_m_s, cfg_.omega_max_rad_s);
  dv_ff_ = clampf(ref.dv_m_s2, 100.0f);
  dw_ff_ = clampf(ref.domega_rad_s2, 1000.0f);
  update_tau_max();
  return kin_;
}

void Controller::update_tau_max() {
  // Per-wheel tau_max from the wheel's own normal force (lateral load transfer II.28), with
  // the lateral force m_t (v w + d dw_ff) of the latest measured v, w. Refreshed at the outer
  // rate: the load transfer changes slowly.
  const float m_t = static_cast<float>(cfg_.robot.m_t()), d = static_cast<float>(cfg_.robot.d);
  const float lat_n = m_t * (odo_.v_m_s() * odo_.omega_rad_s() + d * dw_ff_);
  const slip::NormalForces nf = slip::normal_forces(cfg_.robot, lat_n);
  // the clamp's limit: tau_max less the back-EMF margin (cascade.h; 0 with the clamp off)
  const float mg = cfg_.clamp_enabled ? cfg_.margin_nm : 0.0f;
  out_.tau_max_r_nm = fmaxf(static_cast<float>(slip::tau_max(cfg_.robot, nf.N_r)) - mg, 0.0f);
  out_.tau_max_l_nm = fmaxf(static_cast<float>(slip::tau_max(cfg_.robot, nf.N_l)) - mg, 0.0f);
}

const InnerOut& Controller::start(int32_t enc_r, int32_t enc_l, const Pose& p, const RefSample& ref0) {
  reset(enc_r, enc_l, p);
  outer_step(ref0);
  out_.odo = OdoStatus::kOk;
  return command(0.0f);
}

const InnerOut& Controller::inner_step(int32_t enc_r, int32_t enc_l, float dt_s) {
  out_.odo = odo_.update(enc_r, enc_l, dt_s);
  return command(dt_s);
}

const InnerOut& Controller::command(float dt_s) {
  const float v = odo_.v_m_s(), w = odo_.omega_rad_s();
  const float r = static_cast<float>(cfg_.robot.r), b = static_cast<float>(cfg_.robot.b);
  const float mtd = cfg_.mtd_ff_kg_m;
  const Gains& g = cfg_.gains;

  const float e_v = kin_.v_d_m_s - v;
  const float e_w = kin_.omega_d_rad_s - w;
  const float force = cfg_.m_ff_kg * dv_ff_ - mtd * w * w + g.k_l * e_v + i_v_;
  const float moment = cfg_.I_ff_kgm2 * dw_ff_ + mtd * w * v + g.k_a * e_w + i_w_;
  const WheelPair tau = split_torque(r, b, force, moment);

  const float big = static_cast<float>(cfg_.motor.stall_nm) * 10.0f;
  const float half_dt = (dt_s > 0.0f && dt_s < 1.0f) ? 0.5f * dt_s : 0.0f;
  if (cfg_.clamp_enabled) {
    out_.tau_r_nm = clamp_torque(tau.r, out_.tau_max_r_nm, &out_.clamped_r);
    out_.tau_l_nm = clamp_torque(tau.l, out_.tau_max_l_nm, &out_.clamped_l);
  } else {  // still reject NaN / absurd requests
    out_.tau_r_nm = clamp_torque(tau.r, big, &out_.clamped_r);
    out_.tau_l_nm = clamp_torque(tau.l, big, &out_.clamped_l);
  }
  // Torque->PWM over the coming tick. A clamped wheel gets all of its limit: its back-EMF term
  // follows the speed at the tick's start, i.e. the measured mean speed (that of half a tick
  // ago) advanced over half a tick at the clamped torque's acceleration if it was clamped (same
  // sign) in the last tick too, and its duty ramps at that acceleration over the tick.
  const float ms_over_nl = static_cast<float>(1e-3 / cfg_.motor.no_load_rad_s);
  const int8_t sg_r = out_.clamped_r ? (tau.r > 0.0f ? 1 : -1) : 0;
  const int8_t sg_l = out_.clamped_l ? (tau.l > 0.0f ? 1 : -1) : 0;
  const float alpha_r = sg_r != 0 ? cfg_.wheel_accel_per_nm * out_.tau_r_nm : 0.0f;
  const float alpha_l = sg_l != 0 ? cfg_.wheel_accel_per_nm * out_.tau_l_nm : 0.0f;
  const float adv_r = (sg_r != 0 && sg_r == was_r_) ? alpha_r * half_dt : 0.0f;
  const float adv_l = (sg_l != 0 && sg_l == was_l_) ? alpha_l * half_dt : 0.0f;
  out_.pwm_r = torque_to_pwm(cfg_.motor, out_.tau_r_nm, odo_.omega_r_rad_s() + adv_r, &out_.sat_r);
  out_.pwm_l = torque_to_pwm(cfg_.motor, out_.tau_l_nm, odo_.omega_l_rad_s() + adv_l, &out_.sat_l);
  out_.pwm_slope_r = alpha_r * ms_over_nl;
  out_.pwm_slope_l = alpha_l * ms_over_nl;
  was_r_ = sg_r;
  was_l_ = sg_l;

  // Anti-windup by conditional integration: an integrator is frozen when a wheel it drives is
  // limited (clamp or duty) and the error would push that wheel further into the limit.
  // dtau_r/dF, dtau_r/dM > 0; dtau_l/dF > 0, dtau_l/dM < 0.
  const float s_r = (out_.clamped_r || out_.sat_r) ? signf(tau.r) : 0.0f;
  const float s_l = (out_.clamped_l || out_.sat_l) ? signf(tau.l) : 0.0f;
  if (dt_s > 0.0f && dt_s < 1.0f) {
    const bool block_v = (s_r * e_v > 0.0f) || (s_l * e_v > 0.0f);
    const bool block_w = (s_r * e_w > 0.0f) || (-s_l * e_w > 0.0f);
    if (!block_v) i_v_ = clampf(i_v_ + g.k_il * e_v * dt_s, cfg_.integ_max_n);
    if (!block_w) i_w_ = clampf(i_w_ + g.k_ia * e_w * dt_s, cfg_.integ_max_nm);
  }
  return out_;
}

}  // namespace ctl
