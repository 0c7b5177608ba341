// Velocity-command reference: the reference source of drive mode (protocol message Drive), beside
// the canned profiles of reference.h. The host commands a target (v, omega) -- ROS cmd_vel, as
// diff_drive_controller takes it -- and the reference ramps to it within acceleration limits and
// integrates its pose, so the tracking cascade sees an ordinary reference sample (pose, v_r,
// omega_r and their derivatives).
//
// One step per outer tick (period dt), with the target latched at that tick:
//   dv = clamp(v_target - v_k, +-accel dt),  dw = clamp(w_target - w_k, +-alpha dt)
//   sample k = (pose_k, v_k, w_k, dv/dt, dw/dt): the reference now and its acceleration over the
//            coming period (the feed-forward the velocity loop uses is the true one)
//   v_k+1 = v_k + dv, w_k+1 = w_k + dw
//   pose_k+1 = pose_k advanced along the mean speeds (midpoint rule):
//     ds = (v_k + v_k+1)/2 dt, dphi = (w_k + w_k+1)/2 dt,
//     x += ds cos(phi + dphi/2), y += ds sin(phi + dphi/2), phi += dphi
// The first tick (k = 0) starts at rest at the origin facing +x, like every canned path.
// The fixed-point step is what the firmware runs and what lib/closedloop replays; the float one
// is its specification (test_control_drive compares them).
//
// Command timeout (DriveLatch): after cmd_timeout without a Drive the target is 0, so the
// reference ramps to rest and holds (diff_drive_controller's cmd_vel_timeout).
#ifndef CONTROL_DRIVE_H
#define CONTROL_DRIVE_H

#include <stdint.h>

#include <control/fixmath.h>
#include <control/reference.h>

namespace ctl {

/// Acceleration limits of drive mode (> 0; the protocol's SetDriveLimits ranges).
struct DriveLimits {
  float accel_m_s2;    ///< |dv_r/dt| limit
  float alpha_rad_s2;  ///< |domega_r/dt| limit
  constexpr bool valid() const {
    return accel_m_s2 > 0.0f && accel_m_s2 <= 20.0f && alpha_rad_s2 > 0.0f && alpha_rad_s2 <= 60.0f;
  }
};

/// Float drive reference (the specification of DriveReferenceQ).
class DriveReference {
 public:
  DriveReference(const DriveLimits& lim, float dt_s) : lim_(lim), dt_(dt_s) { reset(); }
  /// At rest at the origin facing +x.
  void reset() { x_ = y_ = phi_ = v_ = w_ = 0.0f; }
  /// The sample at this outer tick for the target latched now; advances to the next tick.
  RefSample step(float v_target_m_s, float omega_target_rad_s);

 private:
  DriveLimits lim_;
  float dt_;
  float x_, y_, phi_, v_, w_;
};

/// Drive targets in the controller's formats from the Drive message's raw units (mm/s, mrad/s),
/// rounded to nearest: v Q12 m/s, omega Q11 rad/s (|v| <= 4 m/s, |omega| <= 15 rad/s fit).
int16_t drive_v_q12(int16_t v_mm_s);
int16_t drive_omega_q11(int16_t omega_mrad_s);

/// Fixed-point constants of the drive reference for an outer period of dt_us (constexpr).
struct DriveConfigQ {
  int16_t dv_step_q12;  ///< accel dt, m/s Q12 (the largest speed change per tick)
  int16_t dw_step_q11;  ///< alpha dt, rad/s Q11
  int16_t inv_dt_hz;    ///< 1/dt, 1/s (rounded)
  int16_t ds_q12;       ///< dt/2 2^8, Q12: ds_q20 = (v_k + v_k+1)_q12 ds_q12 >> 12
  /// K = dt/2 2^32/(2 pi) 2^-11 (8344.4 at 50 ms) as its whole part and its fraction in Q15:
  /// dphi_b32 = S K = S dphi_int + (S dphi_frac_q15 >> 15), S = (w_k + w_k+1)_q11
  int16_t dphi_int;
  int16_t dphi_frac_q15;
  bool ok;              ///< limits valid and every constant fits (1 ms <= dt <= 62 ms)

  constexpr DriveConfigQ(const DriveLimits& l, uint32_t dt_us)
      : dv_step_q12(fits(l.accel_m_s2 * 1e-6 * dt_us, 12) ? q(l.accel_m_s2 * 1e-6 * dt_us, 12) : 0),
        dw_step_q11(fits(l.alpha_rad_s2 * 1e-6 * dt_us, 11) ? q(l.alpha_rad_s2 * 1e-6 * dt_us, 11) : 0),
        inv_dt_hz(dt_us >= 1000 ? static_cast<int16_t>((1000000UL + dt_us / 2) / dt_us) : 0),
        ds_q12(fits(0.5e-6 * dt_us * 256.0, 12) ? q(0.5e-6 * dt_us * 256.0, 12) : 0),
        dphi_int(fits(k_phi(dt_us), 0) ? static_cast<int16_t>(k_phi(dt_us)) : 0),
        dphi_frac_q15(fits(k_phi(dt_us), 0)
                          ? q(k_phi(dt_us) - static_cast<double>(static_cast<int16_t>(k_phi(dt_us))), 15) : 0),
        ok(l.valid() && dt_us >= 1000 && fits(l.accel_m_s2 * 1e-6 * dt_us, 12) &&
           fits(l.alpha_rad_s2 * 1e-6 * dt_us, 11) && fits(0.5e-6 * dt_us * 256.0, 12) &&
           k_phi(dt_us) < 17000.0) {}

 private:
  static constexpr bool fits(double v, int shift) { return v * fx::pow2(shift) < 32767.0 && v >= 0.0; }
  static constexpr int16_t q(double v, int shift) {
    return fx::q_const(v, shift) > 32767 ? static_cast<int16_t>(32767) : static_cast<int16_t>(fx::q_const(v, shift));
  }
  static constexpr double k_phi(uint32_t dt_us) { return 0.5e-6 * dt_us * 4294967296.0 / 6.283185307179586 / 2048.0; }
};

/// Fixed-point drive reference (the firmware's; no float, no division).
class DriveReferenceQ {
 public:
  DriveReferenceQ() { reset(); }
  void reset() {
    x_q20_ = y_q20_ = 0;
    phi_b32_ = 0;
    v_q12_ = 0;
    w_q11_ = 0;
  }
  /// The sample at this outer tick for the target latched now (drive_v_q12/drive_omega_q11);
  /// advances to the next tick. Everything saturates.
  RefSampleQ step(const DriveConfigQ& c, int16_t v_target_q12, int16_t omega_target_q11);

 private:
  int32_t x_q20_, y_q20_;
  uint32_t phi_b32_;
  int16_t v_q12_, w_q11_;
};

/// The drive command as latched by the outer loop: the last Drive received, or 0 once
/// cmd_timeout has passed since it (board time in us, wrap-safe).
class DriveLatch {
 public:
  DriveLatch() : v_mm_s_(0), w_mrad_s_(0), rx_us_(0) {}
  void received(int16_t v_mm_s, int16_t omega_mrad_s, uint32_t now_us) {
    v_mm_s_ = v_mm_s;
    w_mrad_s_ = omega_mrad_s;
    rx_us_ = now_us;
  }
  bool timed_out(uint32_t now_us, uint32_t timeout_us) const { return now_us - rx_us_ >= timeout_us; }
  int16_t v_mm_s(uint32_t now_us, uint32_t timeout_us) const { return timed_out(now_us, timeout_us) ? 0 : v_mm_s_; }
  int16_t omega_mrad_s(uint32_t now_us, uint32_t timeout_us) const {
    return timed_out(now_us, timeout_us) ? 0 : w_mrad_s_;
  }

 private:
  int16_t v_mm_s_, w_mrad_s_;
  uint32_t rx_us_;
};

}  // namespace ctl

#endif  // CONTROL_DRIVE_H
