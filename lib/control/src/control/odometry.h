// Encoder odometry of the axle centre o (thesis III.1-III.4), float and fixed point.
//
// Derivation. Over one sample the wheel angles change by dth_r = 2 pi dn_r / ppr and
// dth_l = 2 pi dn_l / ppr. Assuming constant wheel speeds within the sample, o moves on a
// circular arc of length ds = r (dth_r + dth_l) / 2 while the heading turns by
// dphi = r (dth_r - dth_l) / (2 b)  (III.2; a faster right wheel turns left).
// Integrating xdot = v cos(phi), ydot = v sin(phi) exactly along the arc gives
//     x += ds * sinc(dphi/2) * cos(phi + dphi/2)
//     y += ds * sinc(dphi/2) * sin(phi + dphi/2)          sinc(a) = sin(a)/a.
// This is III.3 and III.4 rewritten: b(v_r+v_l)/(v_r-v_l) (sin phi1 - sin phi0) =
// ds/dphi * 2 cos(phi_mid) sin(dphi/2) = ds sinc(dphi/2) cos(phi_mid), and for y
// ds/dphi (cos phi0 - cos phi1) -- III.4 has cos phi1 - cos phi0, i.e. the wrong sign.
// The sinc form has no division by (v_r - v_l): the straight-line limit is sinc(0) = 1 with
// no loss of precision.
//
// Encoder counts are cumulative int32 that may wrap; the increment is taken modulo 2^32.
#ifndef CONTROL_ODOMETRY_H
#define CONTROL_ODOMETRY_H

#include <stdint.h>

#include <control/fixmath.h>

namespace ctl {

/// Result of an update. Non-zero values are errors; the state is still kept finite.
enum class OdoStatus : uint8_t {
  kOk = 0,
  kBadConfig = 1,   ///< radius, half track or counts per revolution not positive
  kBadDt = 2,       ///< dt not positive (or not finite): pose updated, speeds set to 0
  kCountJump = 3,   ///< a count increment exceeded kMaxStepCounts: increment clamped
};

/// Largest accepted count increment per wheel and update (8.8 wheel turns; the motor's
/// no-load speed gives about 270 counts per 25 ms).
static const int32_t kMaxStepCounts = 16383;

/// The wheel rate is updated to first order (no division) while dt is within this many
/// microseconds of the dt of the last division (or of the reset's rate state).
static const int16_t kRateWindowUs = 63;

/// Constant configuration.
struct OdometryConfig {
  float wheel_radius_m;
  float half_track_m;      ///< b, half the wheel separation
  int32_t counts_per_rev;  ///< encoder counts per wheel revolution (slip::kEncoderPpr)
  constexpr bool valid() const { return wheel_radius_m > 0.0f && half_track_m > 0.0f && counts_per_rev > 0; }
};

struct Pose {
  float x_m;
  float y_m;
  float phi_rad;  ///< wrapped to [-pi, pi)
};

/// Float odometry (host and AVR).
class Odometry {
 public:
  explicit Odometry(const OdometryConfig& cfg);
  /// Start from pose p with the encoders reading (enc_r, enc_l).
  void reset(int32_t enc_r, int32_t enc_l, const Pose& p);
  /// New cumulative counts after dt_s seconds.
  OdoStatus update(int32_t enc_r, int32_t enc_l, float dt_s);

  const Pose& pose() const { return pose_; }
  float omega_r_rad_s() const { return w_r_; }  ///< wheel speeds, III.1
  float omega_l_rad_s() const { return w_l_; }
  float v_m_s() const { return v_; }            ///< v = r (w_r + w_l) / 2
  float omega_rad_s() const { return w_; }      ///< omega = r (w_r - w_l) / (2b)

 private:
  OdometryConfig cfg_;
  float rad_per_count_;
  int32_t last_r_, last_l_;
  Pose pose_;
  float w_r_, w_l_, v_, w_;
};

/// The cached wheel-rate state for one dt: what OdometryQ's division (set_dt()) leaves, and
/// what ControlConfigQ precomputes for the nominal dt so that a reset needs no division.
struct RateQ {
  uint32_t dt_us;         ///< dt of the division (0: none)
  int32_t per_count_q11;  ///< wheel_rate_q11 / dt_us
  uint16_t div_q10;       ///< the same in Q10 when it fits 16 bits (dt >= 13.5 ms), else 0
  uint16_t slope_q12;     ///< div_q10 / dt_us (Q10 units per us, Q12; the first-order update), 0: none
};

namespace detail {
/// The rate formulas, shared by the run-time division (OdometryQ::set_dt_wide, fx:: arithmetic)
/// and the configuration's rate_for() (plain C, constexpr): q = floor(k / dt), its Q10 form
/// r = (q + 1) >> 1 truncated to 16 bits when q < 2^17 (else 0), and the slope
/// r / dt = r^2 / (k / 2) as floor(floor(r^2 / 2^16) inv / 2^16), inv = 8192 / k in Q32 (0 unless
/// 0 < r < 64000 and inv != 0; see OdometryQ::set_dt for the error of the first-order update).
constexpr uint16_t rate_q10(int32_t q) { return static_cast<uint16_t>(q < 131072L ? (q + 1) >> 1 : 0); }
template <class Ops>
constexpr uint16_t rate_slope(uint16_t r, uint16_t inv) {
  return (r != 0 && r < 64000U && inv != 0)
             ? static_cast<uint16_t>(Ops::mul(static_cast<uint16_t>(Ops::mul(r, r) >> 16), inv) >> 16) : 0;
}
/// The arithmetic in plain C.
struct RateOpsC {
  static constexpr uint32_t mul(uint16_t a, uint16_t b) { return static_cast<uint32_t>(a) * b; }
};
constexpr RateQ rate_from_q(uint32_t dt_us, int32_t q, uint16_t inv) {
  return RateQ{dt_us, q, rate_q10(q), rate_slope<RateOpsC>(rate_q10(q), inv)};
}
}  // namespace detail

/// Fixed-point configuration, derived from OdometryConfig at compile time (constexpr).
struct OdometryConfigQ {
  int32_t ds_per_count_q44;    ///< r pi / ppr (metres per count of n_r + n_l), Q44
  uint32_t dphi_per_count_b32; ///< r / (2b) * 2pi / ppr per count of n_r - n_l, binary angle
  uint16_t dphi_per_count_frac;///< ...its fraction below one binary-angle unit, Q16
  int32_t wheel_rate_q11;      ///< 2pi / ppr * 2^8 * 1e6, Q11 (to get rad/s Q8 from counts/us)
  int16_t half_r_q16;          ///< r / 2, Q16
  int16_t r_over_2b_q15;       ///< r / (2b), Q15
  uint16_t inv_rate_q32;       ///< 8192 / wheel_rate_q11, Q32 (0: does not fit, no linear dt update)
  bool ok;                     ///< the float configuration was valid and representable

  constexpr explicit OdometryConfigQ(const OdometryConfig& c)
      : ds_per_count_q44(ok_range(c) ? fx::q_const(c.wheel_radius_m * 3.14159265358979 / c.counts_per_rev, 44) : 0),
        dphi_per_count_b32(static_cast<uint32_t>(dphi_b32(c))),
        dphi_per_count_frac(static_cast<uint16_t>((dphi_b32(c) - static_cast<double>(
                                                       static_cast<uint32_t>(dphi_b32(c)))) * 65536.0)),
        wheel_rate_q11(c.valid() ? fx::q_const(6.283185307179586 / c.counts_per_rev * 256.0 * 1.0e6, 11) : 0),
        half_r_q16(c.valid() && c.wheel_radius_m < 0.5f
                       ? static_cast<int16_t>(fx::q_const(c.wheel_radius_m / 2.0, 16)) : 0),
        r_over_2b_q15(ok_range(c) ? static_cast<int16_t>(fx::q_const(c.wheel_radius_m / (2.0 * c.half_track_m), 15)) : 0),
        inv_rate_q32(c.valid() && inv_rate(c) < 65535.0 ? static_cast<uint16_t>(fx::q_const(inv_rate(c), 0)) : 0),
        ok(ok_range(c)) {}

  /// The rate state a division at dt_us leaves (OdometryQ::set_dt), computed in plain C
  /// (bit-identical; checked in test_control_odometry and on the AVR by bench/control_avr).
  constexpr RateQ rate_for(uint32_t dt_us) const {
    return dt_us != 0 ? detail::rate_from_q(dt_us, static_cast<int32_t>(static_cast<uint32_t>(wheel_rate_q11) / dt_us), inv_rate_q32)
                      : RateQ{0, 0, 0, 0};
  }

  static constexpr double inv_rate(const OdometryConfig& c) {
    return 8192.0 / (6.283185307179586 / c.counts_per_rev * 256.0 * 1.0e6 * 2048.0) * 4294967296.0;
  }

  /// r/(2b) 2pi/ppr in binary-angle units (0 for an invalid configuration).
  static constexpr double dphi_b32(const OdometryConfig& c) {
    return ok_range(c) ? c.wheel_radius_m / (2.0 * c.half_track_m) / c.counts_per_rev * 4294967296.0 : 0.0;
  }
  /// Valid and representable: r pi/ppr < 2^-13 m (Q44 fits int32; r < 7.2 cm at the robot's kEncoderPpr),
  /// r/(2b) < 0.99, ppr >= 1600 (wheel_rate_q11 fits).
  static constexpr bool ok_range(const OdometryConfig& c) {
    return c.valid() && c.wheel_radius_m * 3.14159265358979 / c.counts_per_rev < 1.2207e-4 &&
           c.wheel_radius_m / (2.0 * c.half_track_m) < 0.99 && c.counts_per_rev >= 1600;
  }
};

/// Fixed-point pose: position Q20 metres (range +-2048 m, 0.95 um), heading binary angle.
struct PoseQ {
  int32_t x_q20;
  int32_t y_q20;
  uint32_t phi_b32;
};

/// Fixed-point odometry (no float anywhere; AVR inner loop).
///
/// The pose integration (one exact arc per sample, with sine and cosine) can be deferred:
/// update_deferred() computes the wheel speeds at once and queues the sample's count
/// increments; the arcs are integrated, one per sample and in order, the next time the pose is
/// read (pose(), or the controller's outer step). The result is bit-identical to integrating
/// at every update -- only the moment the cycles are spent changes.
class OdometryQ {
 public:
  /// Samples whose arcs can wait (the outer step runs every second inner step); a further
  /// update_deferred() integrates the oldest at once.
  static const uint8_t kMaxPending = 2;

  explicit OdometryQ(const OdometryConfigQ& cfg);
  /// Start from pose p with the encoders reading (enc_r, enc_l). `rate`: the rate state to
  /// start from (the configuration's rate_for(dt) of the expected dt: a first update with dt
  /// within +-63 us of it then needs no division); none by default.
  void reset(int32_t enc_r, int32_t enc_l, const PoseQ& p, const RateQ& rate = RateQ{0, 0, 0, 0});
  /// New cumulative counts after dt_us microseconds: wheel speeds and pose.
  OdoStatus update(int32_t enc_r, int32_t enc_l, uint32_t dt_us);
  /// The same, but the pose arc of this sample is queued (integrated when the pose is read).
  /// Inline: it is the first part of the controller's inner step.
  OdoStatus update_deferred(int32_t enc_r, int32_t enc_l, uint32_t dt_us);

  /// The pose after the latest update (integrates any queued arcs first: logically const).
  const PoseQ& pose() const {
    if (n_pending_ != 0) integrate_pending();
    return pose_;
  }
  /// Number of queued (not yet integrated) samples.
  uint8_t pending() const { return n_pending_; }
  int16_t omega_r_q8() const { return w_r_q8_; }   ///< rad/s, Q8 (saturated at +-128)
  int16_t omega_l_q8() const { return w_l_q8_; }
  int16_t v_q12() const { return v_q12_; }         ///< m/s, Q12
  int16_t omega_q11() const { return w_q11_; }     ///< rad/s, Q11

 private:
  /// Modulo-2^32 count increment, clamped to +-kMaxStepCounts (sets *jumped then).
  static CTL_INLINE int16_t count_step_q(int32_t now, int32_t last, bool* jumped) {
    const uint32_t d = static_cast<uint32_t>(now) - static_cast<uint32_t>(last);
    // in range iff d + kMax (mod 2^32) <= 2 kMax: one unsigned compare
    if (d + static_cast<uint32_t>(kMaxStepCounts) <= 2UL * kMaxStepCounts) return static_cast<int16_t>(d);
    *jumped = true;
    return static_cast<int16_t>(static_cast<int32_t>(d) > 0 ? kMaxStepCounts : -kMaxStepCounts);
  }
  friend struct OdometryQProbe;  // bench/control_avr: set_dt() (AVR assembly) vs set_dt_wide()
  /// New dt: the cached wheel rate per count (a division) and the first-order slope; on the
  /// AVR, for 13.5 ms < dt < 32.8 ms, one inline-assembly block; otherwise set_dt_wide().
  void set_dt(uint32_t dt_us);
  /// The same in C (any dt > 0).
  void set_dt_wide(uint32_t dt_us) __attribute__((noinline));
  void integrate_pending() const;
  void integrate_arc(int16_t dn_r, int16_t dn_l) const;

  OdometryConfigQ cfg_;
  int32_t last_r_, last_l_;
  // The pose and its carried residues change only by integrating queued arcs (see pose()).
  mutable PoseQ pose_;
  mutable uint16_t phi_frac_;
  mutable uint8_t x_frac_, y_frac_;  // position below Q20 (Q28 residue)
  mutable uint8_t n_pending_;
  int16_t pend_r_[kMaxPending], pend_l_[kMaxPending];  // queued count increments, oldest first
  uint32_t last_dt_us_;         // dt of the current rate
  RateQ div_;                   // the last exact division (or the reset's rate state)
  uint16_t rate_q10_;           // rate for last_dt_us_ (Q10), 0: use the 32-bit path
  int16_t w_r_q8_, w_l_q8_, v_q12_, w_q11_;
};

CTL_INLINE OdoStatus OdometryQ::update_deferred(int32_t enc_r, int32_t enc_l, uint32_t dt_us) {
  if (!cfg_.ok) return OdoStatus::kBadConfig;
  bool jumped = false;
  const int16_t dn_r = count_step_q(enc_r, last_r_, &jumped);
  const int16_t dn_l = count_step_q(enc_l, last_l_, &jumped);
  last_r_ = enc_r;
  last_l_ = enc_l;
  if (n_pending_ == kMaxPending) integrate_pending();  // nobody read the pose: catch up
  pend_r_[n_pending_] = dn_r;
  pend_l_[n_pending_] = dn_l;
  ++n_pending_;

  // Wheel speeds, rad/s Q8: dn * (2pi/ppr 2^8 1e6 / dt_us). The rate per count is cached and
  // recomputed when dt changes -- in the firmware that is nearly every step (dt is measured in
  // microseconds), hence the short division of set_dt().
  OdoStatus st = jumped ? OdoStatus::kCountJump : OdoStatus::kOk;
  if (dt_us == 0) {
    w_r_q8_ = w_l_q8_ = 0;
    st = OdoStatus::kBadDt;
  } else {
    CTL_PROBE(11);
    if (dt_us != last_dt_us_) {
      // dt within +-63 us of the last divided dt (the firmware's jitter): first-order update
      // rate = rate_div - slope (dt - dt_div), error below 2 units of the Q10 rate (3e-5
      // relative; see set_dt). Otherwise the division.
      last_dt_us_ = dt_us;
      const int32_t dd = static_cast<int32_t>(dt_us - div_.dt_us);
      if (div_.slope_q12 != 0 && dd >= -kRateWindowUs && dd <= kRateWindowUs) {
        rate_q10_ = static_cast<uint16_t>(
            div_.div_q10 - static_cast<uint16_t>(fx::rshift_round_nc_lo16<12>(fx::mul_us(div_.slope_q12, static_cast<int16_t>(dd)))));
      } else {
        set_dt(dt_us);
      }
    }
    CTL_PROBE(12);
    if (rate_q10_ != 0 || div_.per_count_q11 == 0) {
      // |rate dn| <= 65535 * 16383 < 2^30: no overflow in the rounding
      w_r_q8_ = fx::rshift_round_nc_sat16<10>(fx::mul_us(rate_q10_, dn_r));
      w_l_q8_ = fx::rshift_round_nc_sat16<10>(fx::mul_us(rate_q10_, dn_l));
    } else {
      w_r_q8_ = fx::sat16(fx::mul32x16_halves<11>(div_.per_count_q11, dn_r));
      w_l_q8_ = fx::sat16(fx::mul32x16_halves<11>(div_.per_count_q11, dn_l));
    }
  }
  CTL_PROBE(13);
  // v and omega from the wheel speeds; the sum and difference saturate at 128 rad/s (v at
  // 2.3 m/s, omega beyond the Q11 range anyway), far above the motor's no-load speed.
  const int16_t sum_q8 = fx::add_sat16(w_r_q8_, w_l_q8_);
  const int16_t diff_q8 = fx::sub_sat16(w_r_q8_, w_l_q8_);
  v_q12_ = fx::rshift_round_nc_sat16<12>(fx::mul_ss(sum_q8, cfg_.half_r_q16));     // Q8*Q16>>12
  w_q11_ = fx::rshift_round_nc_sat16<12>(fx::mul_ss(diff_q8, cfg_.r_over_2b_q15));  // Q8*Q15>>12
  return st;
}

/// Wrap an angle to [-pi, pi).
float wrap_pi(float a_rad);

}  // namespace ctl

#endif  // CONTROL_ODOMETRY_H
