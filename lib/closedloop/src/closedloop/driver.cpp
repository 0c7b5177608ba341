#if !defined(__AVR__)

#include <closedloop/driver.h>

#include <math.h>

namespace cl {

namespace {

const double kTwoPi = 6.283185307179586476925;

uint32_t to_b32(double rad) {
  const double turns = rad / kTwoPi;
  return static_cast<uint32_t>(static_cast<int64_t>(llround((turns - floor(turns)) * 4294967296.0)));
}

double from_b32(uint32_t a) { return static_cast<int32_t>(a) * (kTwoPi / 4294967296.0); }

// Reference time in the fixed-point reference's milliseconds.
uint32_t ref_ms(double t_s) { return static_cast<uint32_t>(llround(fmin(t_s, 32000.0) * 1000.0)); }

int32_t counts(double theta_rad, int32_t ppr) {
  return static_cast<int32_t>(floor(theta_rad * ppr / kTwoPi));
}

void copy_dynamic(const slip::PlantState& from, slip::PlantState* to) {
  to->tau_r_nm = from.tau_r_nm;
  to->tau_l_nm = from.tau_l_nm;
  to->N_r = from.N_r;
  to->N_l = from.N_l;
  to->N_c = from.N_c;
  to->F_r_n = from.F_r_n;
  to->F_l_n = from.F_l_n;
  to->L_r_n = from.L_r_n;
  to->L_l_n = from.L_l_n;
}

uint32_t outer_us(const cl::DriverConfig& c) {
  return static_cast<uint32_t>(llround(c.inner_s * c.outer_every * 1e6));
}

}  // namespace

const char* DriverConfig::check() const {
  if (!(inner_s > 0.0 && inner_s <= 1.0)) return "inner period must be in (0, 1] s";
  if (outer_every < 1) return "the outer step must run every N >= 1 inner ticks";
  if (ppr <= 0) return "encoder counts per turn must be > 0";
  if (!(plant_dt_s > 0.0 && plant_dt_s <= 1.0)) return "plant step must be in (0, 1] s";
  if (rows_per_tick < 1 || rows_per_tick > 1000) return "rows per tick must be in [1, 1000]";
  if (!isfinite(t0_s) || fabs(t0_s) > 1e9) return "t0 must be finite (|t0| <= 1e9 s)";
  if (!drive && !ref.valid()) return "invalid reference (accel in (0,20], cruise in [0,4], |R| in [0.05,100])";
  if (drive) {
    if (!ctl::DriveConfigQ(drive_limits, outer_us(*this)).ok)
      return "invalid drive limits (accel in (0,20] m/s^2, alpha in (0,60] rad/s^2, outer period <= 62 ms)";
    if (n_drive < 0 || (n_drive > 0 && drive_cmds == nullptr)) return "drive commands missing";
    for (int i = 0; i < n_drive; ++i) {
      if (!isfinite(drive_cmds[i].t_s)) return "drive command time not finite";
      if (i > 0 && drive_cmds[i].t_s < drive_cmds[i - 1].t_s) return "drive commands not sorted by time";
    }
  }
  if (fixed_point && !ctl::ControlConfigQ(ctl).ok) return "configuration does not fit the fixed-point formats";
  return "";
}

Driver::Driver(const DriverConfig& cfg, const slip::RobotParams& plant_robot,
               const slip::MotorParams& plant_motor)
    : cfg_(cfg),
      cfg_q_(cfg.ctl),
      ref_q_(cfg.ref),
      drive_q_(cfg.drive_limits, outer_us(cfg)),
      drf_(cfg.drive_limits, static_cast<float>(cfg.inner_s * cfg.outer_every)),
      drive_i_(0),
      fc_(cfg.ctl),
      qc_(cfg_q_),
      plant_(plant_robot, plant_motor),
      k_(0),
      out_() {
  reset(0.0, 0.0, 0.0);
}

void Driver::reset(double x_m, double y_m, double phi_rad) {
  plant_.reset(x_m, y_m, phi_rad);
  plant_.set_time(cfg_.t0_s);
  start_f_ = ctl::Pose{static_cast<float>(x_m), static_cast<float>(y_m), static_cast<float>(phi_rad)};
  start_q_ = ctl::PoseQ{static_cast<int32_t>(llround(x_m * 1048576.0)),
                        static_cast<int32_t>(llround(y_m * 1048576.0)), to_b32(phi_rad)};
  fc_.reset(0, 0, start_f_);
  qc_.reset(0, 0, start_q_);
  drq_.reset();
  drf_.reset();
  drive_i_ = 0;
  k_ = 0;
}

void Driver::drive_target(int64_t k, int16_t* v, int16_t* w) {
  const double t = cfg_.t0_s + cfg_.inner_s * static_cast<double>(k);
  while (drive_i_ < cfg_.n_drive && cfg_.drive_cmds[drive_i_].t_s <= t + 1e-7) ++drive_i_;
  *v = drive_i_ > 0 ? cfg_.drive_cmds[drive_i_ - 1].v_mm_s : 0;
  *w = drive_i_ > 0 ? cfg_.drive_cmds[drive_i_ - 1].omega_mrad_s : 0;
}

ctl::RefSampleQ Driver::ref_q(int64_t k) {
  if (!cfg_.drive) return ctl::reference_at_q(ref_q_, ref_ms(static_cast<double>(k) * cfg_.inner_s));
  int16_t v, w;
  drive_target(k, &v, &w);
  return drq_.step(drive_q_, ctl::drive_v_q12(v), ctl::drive_omega_q11(w));
}

ctl::RefSample Driver::ref_f(int64_t k) {
  if (!cfg_.drive) return ctl::reference_at(cfg_.ref, static_cast<float>(static_cast<double>(k) * cfg_.inner_s));
  int16_t v, w;
  drive_target(k, &v, &w);
  return drf_.step(v * 1e-3f, w * 1e-3f);
}

void Driver::read_ctl(CtlRow* o) const {
  if (cfg_.fixed_point) {
    const ctl::InnerOutQ& i = qc_.inner();
    const ctl::KinematicOutQ& k = qc_.kinematic();
    const ctl::OdometryQ& od = qc_.odometry();
    *o = CtlRow{i.pwm_r_q15 / 32768.0, i.pwm_l_q15 / 32768.0, i.tau_r_q16 / 65536.0, i.tau_l_q16 / 65536.0,
                i.tau_max_r_q16 / 65536.0, i.tau_max_l_q16 / 65536.0, i.clamped_r, i.clamped_l,
                i.sat_r, i.sat_l, od.omega_r_q8() / 256.0, od.omega_l_q8() / 256.0,
                od.pose().x_q20 / 1048576.0, od.pose().y_q20 / 1048576.0, from_b32(od.pose().phi_b32),
                k.v_d_q12 / 4096.0, k.omega_d_q11 / 2048.0, k.e_x_q12 / 4096.0, k.e_y_q12 / 4096.0,
                from_b32(static_cast<uint32_t>(k.e_phi_b32)), static_cast<int>(i.odo),
                i.slope_r_q15 / 32768.0, i.slope_l_q15 / 32768.0};
  } else {
    const ctl::InnerOut& i = fc_.inner();
    const ctl::KinematicOut& k = fc_.kinematic();
    const ctl::Odometry& od = fc_.odometry();
    *o = CtlRow{i.pwm_r, i.pwm_l, i.tau_r_nm, i.tau_l_nm, i.tau_max_r_nm, i.tau_max_l_nm,
                i.clamped_r, i.clamped_l, i.sat_r, i.sat_l, od.omega_r_rad_s(), od.omega_l_rad_s(),
                od.pose().x_m, od.pose().y_m, od.pose().phi_rad, k.v_d_m_s, k.omega_d_rad_s,
                k.e_x_m, k.e_y_m, k.e_phi_rad, static_cast<int>(i.odo), i.pwm_slope_r, i.pwm_slope_l};
  }
}

const TickOut& Driver::step(slip::PlantState* rows) {
  const int64_t k = k_;
  const double T = cfg_.inner_s;
  TickOut& o = out_;
  o.k = k;
  o.t_s = cfg_.t0_s + T * static_cast<double>(k);
  o.plant = plant_.state();
  o.enc_r = counts(o.plant.theta_r_rad, cfg_.ppr);
  o.enc_l = counts(o.plant.theta_l_rad, cfg_.ppr);
  const bool outer = k % cfg_.outer_every == 0;
  // The row is read after the inner step, before the outer step (as ctl_inner reports it).
  // Tick 0 starts the experiment: reset, outer step with the reference at 0, first command.
  if (k == 0) {
    if (cfg_.fixed_point) qc_.start(o.enc_r, o.enc_l, start_q_, ref_q(0));
    else fc_.start(o.enc_r, o.enc_l, start_f_, ref_f(0));
    read_ctl(&o.ctl);
  } else if (cfg_.fixed_point) {
    qc_.inner_step(o.enc_r, o.enc_l, static_cast<uint32_t>(llround(T * 1e6)));
    read_ctl(&o.ctl);
    if (outer) qc_.outer_step(ref_q(k));
  } else {
    fc_.inner_step(o.enc_r, o.enc_l, static_cast<float>(T));
    read_ctl(&o.ctl);
    if (outer) fc_.outer_step(ref_f(k));
  }
  const bool torque = cfg_.actuator == Actuator::kTorque;
  const double in_r = torque ? o.ctl.tau_cmd_r : o.ctl.pwm_r;
  const double in_l = torque ? o.ctl.tau_cmd_l : o.ctl.pwm_l;
  // Rows on the global grid t0 + i*(T/m), i = k*m + j, so that the row times do not depend on
  // how the run is cut into ticks.
  const int m = cfg_.rows_per_tick;
  const double h_row = T / m;
  const double ramp_ms = cfg_.duty_ramp ? floor(T * 1e3 + 1e-9) - 1.0 : 0.0;
  o.slip_steps = 0;
  o.first_slip_t_s = -1.0;
  for (int j = 0; j < m; ++j) {
    const int64_t i = k * m + j;
    const double t_a = cfg_.t0_s + h_row * static_cast<double>(i);
    const double t_b = cfg_.t0_s + h_row * static_cast<double>(i + 1);
    if (rows) {
      rows[j] = plant_.state();
      rows[j].t_s = t_a;
    }
    const double span = t_b - t_a;
    long steps = static_cast<long>(ceil(span / cfg_.plant_dt_s - 1e-9));
    if (steps < 1) steps = 1;
    const double h = span / static_cast<double>(steps);
    for (long s = 0; s < steps; ++s) {
      if (torque) {
        plant_.step_torque(in_r, in_l, h);
      } else {
        // the firmware's 1 kHz tick adds the slope to a clamped wheel's duty every millisecond
        // after the inner tick, ramp_ms times at most
        const double tau_ms = (h_row * j + h * static_cast<double>(s)) * 1e3;
        const double n_ms = fmin(floor(tau_ms + 1e-9), ramp_ms);
        plant_.step_duty(fmin(fmax(in_r + o.ctl.pwm_slope_r * n_ms, -1.0), 1.0),
                         fmin(fmax(in_l + o.ctl.pwm_slope_l * n_ms, -1.0), 1.0), h);
      }
      const slip::PlantState& st = plant_.state();
      if (s == 0) {
        if (rows) copy_dynamic(st, &rows[j]);
        if (j == 0) copy_dynamic(st, &o.plant);
      }
      if (st.slipping_r || st.slipping_l) {
        if (o.slip_steps == 0) o.first_slip_t_s = st.t_s;
        ++o.slip_steps;
      }
    }
    plant_.set_time(t_b);
  }
  o.plant.t_s = o.t_s;
  ++k_;
  return o;
}

}  // namespace cl

#endif  // !__AVR__
