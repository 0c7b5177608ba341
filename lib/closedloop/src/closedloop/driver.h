// Host-only closed-loop driver: the firmware's cascade (lib/control, float or fixed point) in
// closed loop with the lib/slipmodel plant, stepped forward one inner tick at a time.
//
// One tick k (board time t0 + k*inner_s, reference time k*inner_s):
//   1. the encoders read floor(theta * ppr / 2pi) of the plant's wheel angles;
//   2. the inner step runs on those counts with dt = inner_s;
//   3. every outer_every ticks, the outer step runs after it (reference sampled at k*inner_s);
//      tick 0 is the experiment's start tick instead (ctl start(): reset to the start pose, the
//      outer step with the reference at 0, the first command from rest), as in the firmware;
//   4. the plant is advanced with the inner step's duty (or, with Actuator::kTorque, its torque
//      command after the clamp) held for one inner period, in rows_per_tick rows; each row is
//      integrated in ceil(row/plant_dt) equal Euler steps and the plant clock is re-aligned at
//      the row's end (as the plant's C ABI simulate does, so both give the same numbers).
// Nothing here is physics or control: both live in their libraries.
#ifndef CLOSEDLOOP_DRIVER_H
#define CLOSEDLOOP_DRIVER_H

#if !defined(__AVR__)

#include <stdint.h>

#include <control/cascade.h>
#include <control/cascade_q.h>
#include <control/drive.h>
#include <control/reference.h>
#include <slipmodel/plant.h>

namespace cl {

enum class Actuator { kDuty = 0, kTorque = 1 };

/// A drive-mode target as the firmware latched it: from board time t_s on (an outer tick), the
/// Drive values v (mm/s) and omega (mrad/s), as the message carries them.
struct DriveCommand {
  double t_s;
  int16_t v_mm_s, omega_mrad_s;
};

struct DriverConfig {
  bool fixed_point = true;
  /// The controller's configuration (its nominal robot and motor, gains, clamp switch); the
  /// plant's parameters are the plant's own (Driver::plant()).
  ctl::ControlConfig ctl = ctl::make_control_config(slip::RobotParams(), slip::MotorParams(),
                                                    ctl::default_gains(), true);
  ctl::ReferenceSpec ref{ctl::PathKind::kLine, 1.0f, 0.0f, 0.0f};
  /// Drive mode instead of `ref` (lib/control drive.h): at each outer tick the target is the
  /// last of the n_drive commands (sorted by time, caller-owned) at or before the tick's board
  /// time (0 before the first), stepped with drive_limits as the firmware's outer task does.
  bool drive = false;
  ctl::DriveLimits drive_limits{1.0f, 4.0f};
  const DriveCommand* drive_cmds = nullptr;
  int n_drive = 0;
  double t0_s = 0.0;        ///< board (plant) time of tick 0, where the reference time is 0
  double inner_s = 0.025;   ///< inner period
  int outer_every = 2;      ///< outer step every N inner ticks (tick 0 included)
  int32_t ppr = slip::kEncoderPpr;  ///< encoder counts per wheel turn (the plant's encoders)
  double plant_dt_s = 5e-4; ///< largest Euler step
  int rows_per_tick = 1;    ///< plant rows per tick (see TickOut::rows)
  Actuator actuator = Actuator::kDuty;
  /// The firmware's 1 kHz ramp of a clamped wheel's duty (CtlRow::pwm_slope_*); off: the duty
  /// is held over the tick (a recorder whose firmware does not ramp, e.g. the truth simulator)
  bool duty_ramp = true;

  /// Empty when usable, else what is wrong.
  const char* check() const;
};

/// The controller's outputs of one tick after its inner step (before the outer step of the
/// same tick, as the C ABI's ctl_inner reports them), in SI units (fixed point converted).
struct CtlRow {
  double pwm_r, pwm_l;             ///< duty in [-1, 1]
  double tau_cmd_r, tau_cmd_l;     ///< N m, after the clamp
  double tau_max_r, tau_max_l;     ///< N m
  bool clamped_r, clamped_l, sat_r, sat_l;
  double omega_r, omega_l;         ///< board wheel speeds, rad/s
  double x_odo_m, y_odo_m, phi_odo_rad;  ///< odometry pose after the inner step
  double v_d_m_s, omega_d_rad_s;   ///< velocity command the inner step used (from the last
                                   ///< outer step before this tick's)
  double e_x_m, e_y_m, e_phi_rad;  ///< tracking errors of that outer step
  int odo_status;                  ///< ctl::OdoStatus
  double pwm_slope_r, pwm_slope_l; ///< duty added every millisecond over the coming tick
                                   ///< (clamped wheels; the firmware's 1 kHz ramp)
};

struct TickOut {
  int64_t k;             ///< tick index
  double t_s;            ///< board time of the tick
  int32_t enc_r, enc_l;  ///< counts the inner step read
  CtlRow ctl;
  /// The plant at the tick: kinematic fields at t_s, the dynamic ones (torques, normal and
  /// contact forces) of the first Euler step after it.
  slip::PlantState plant;
  int slip_steps;        ///< Euler steps of this tick that ended with a wheel slipping
  double first_slip_t_s; ///< plant time at the end of the first of them, -1 if none
};

class Driver {
 public:
  explicit Driver(const DriverConfig& cfg, const slip::RobotParams& plant_robot = slip::RobotParams(),
                  const slip::MotorParams& plant_motor = slip::MotorParams());

  /// The plant, to set parameters and effects (slip::plant_set). Call reset() afterwards.
  slip::Plant& plant() { return plant_; }
  const DriverConfig& config() const { return cfg_; }

  /// Plant at rest at (x, y, phi) at time t0_s, encoders at 0, controller reset to that pose.
  void reset(double x_m, double y_m, double phi_rad);

  /// Runs one tick. rows, when not null, receives rows_per_tick plant states (row j at
  /// t_s + j*inner_s/rows_per_tick: kinematic fields at that time, dynamic ones of the row's
  /// first Euler step).
  const TickOut& step(slip::PlantState* rows = nullptr);

 private:
  void read_ctl(CtlRow* o) const;
  /// The reference of the outer step of tick k (Start profile or drive mode).
  ctl::RefSampleQ ref_q(int64_t k);
  ctl::RefSample ref_f(int64_t k);
  void drive_target(int64_t k, int16_t* v_mm_s, int16_t* w_mrad_s);

  DriverConfig cfg_;
  ctl::ControlConfigQ cfg_q_;
  ctl::ReferenceSpecQ ref_q_;
  ctl::DriveConfigQ drive_q_;
  ctl::DriveReferenceQ drq_;
  ctl::DriveReference drf_;
  int drive_i_;  // commands before drive_i_ have started
  ctl::Controller fc_;
  ctl::ControllerQ qc_;
  slip::Plant plant_;
  int64_t k_;
  TickOut out_;
  ctl::Pose start_f_;   // the start pose, for the start tick
  ctl::PoseQ start_q_;
};

}  // namespace cl

#endif  // !__AVR__
#endif  // CLOSEDLOOP_DRIVER_H
