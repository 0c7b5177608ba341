#include "app.h"

#include <avr/io.h>
#include <string.h>

#include <control/cascade.h>
#include <control/cascade_q.h>
#include <control/drive.h>
#include <control/odometry.h>
#include <control/reference.h>
#include <protocol/frame.h>
#include <protocol/messages.h>
#include <protocol/replies.h>
#include <slipmodel/motor.h>
#include <slipmodel/params.h>

#include "board.h"
#include "boot.h"
#include "cycles.h"
#include "encoder.h"
#include "motor.h"
#include "xbee.h"

#ifndef FIRMWARE_ID
#define FIRMWARE_ID 0UL
#endif

extern "C" {
volatile uint8_t g_fault_hang;
}

namespace {

// Host timeout: the brake must be on within 500 ms of the last frame that decoded to a known
// host message (handle_frame; unknown types and wrong lengths do not count). The check runs
// every main-loop iteration, which can wait up to ~1.5 ms behind the tasks, so it fires at
// 498.5 ms of silence (board time in us, not the 1 ms tick).
const uint32_t kHostTimeoutUs = 498500ul;

void inner_task();
void outer_task();
void telemetry_task();

// Constant task table (config) -- runtime data lives in sched.cpp. Periods and budgets come
// from protocol/protocol.json (proto::k*), the one place the host also reads them from.
const TaskConfig kTasks[] = {
    {inner_task, static_cast<uint16_t>(proto::kInnerPeriodUs / proto::kSchedTickUs), 0, proto::kInnerBudgetCycles},
    {outer_task, static_cast<uint16_t>(proto::kOuterPeriodUs / proto::kSchedTickUs), 0, proto::kOuterBudgetCycles},
    // phase 2 ms: 2 + 20 k is never a multiple of 25, so telemetry never waits for the loops
    {telemetry_task, static_cast<uint16_t>(proto::kTelemetryPeriodUs / proto::kSchedTickUs), 2,
     proto::kTelemetryBudgetCycles},
};
static_assert(sizeof kTasks / sizeof kTasks[0] == proto::kTaskCount, "task table vs protocol");
// The encoders' counts per wheel turn (board wiring) are the model's: the controller and the
// simulators convert counts to angles with slip::kEncoderPpr.
static_assert(ENC_COUNTS_PER_REV == slip::kEncoderPpr, "the firmware's encoder counts are the model's");
// The host's timing checks convert cycles to time at protocol.json's clock: it is the board's.
static_assert(proto::kFcpuHz == F_CPU, "protocol.json timing.f_cpu_hz != the board's F_CPU");
static_assert(proto::kSchedTickUs * SCHED_TICK_HZ == 1000000UL, "protocol.json timing.sched_tick_us != board.h's tick");
static_assert(ENC_COUNTS_PER_REV >= 1 && ENC_COUNTS_PER_REV <= 65535, "Params.encoder_ppr is a u16");
// the protocol's controller codes are lib/control's Variant values (the C ABI's "controller"
// key, which the analyzer's replay sets from meta.json controller_variant)
static_assert(static_cast<uint8_t>(ctl::Variant::kImproved) == proto::kControllerImproved &&
                  static_cast<uint8_t>(ctl::Variant::kThesis) == proto::kControllerThesis &&
                  ctl::kVariantCount == 2,
              "protocol.json enum controller != ctl::Variant");

// ---- configuration (changed only by commands, while idle) ----
slip::RobotParams g_robot;
const slip::MotorParams kMotor = slip::datasheet_motor();
slip::MotorImperfections g_motor_fit;    // back-EMF ratio and voltage drop (SetModel)
slip::MotorParams g_motor = kMotor;      // the motor the torque->duty map assumes: kMotor with g_motor_fit
bool g_clamp_on = true;
bool g_params_default = true;
ctl::Variant g_variant = ctl::Variant::kImproved;  // velocity loop (SetController)
// drive mode (Drive, SetDriveLimits): limits, timeout, the reference's constants for the outer period
uint32_t g_drive_timeout_us = proto::kDriveCmdTimeoutDefaultUs;
ctl::DriveConfigQ g_drive_cfg{ctl::DriveLimits{proto::kDriveAccelDefault, proto::kDriveAlphaDefault},
                              proto::kOuterPeriodUs};

ctl::ControlConfig make_cfg(const slip::RobotParams& robot, const slip::MotorParams& motor) {
    return ctl::make_control_config(robot, motor, ctl::gains_for(g_variant), g_clamp_on, g_variant);
}
ctl::ControlConfig make_cfg() { return make_cfg(g_robot, g_motor); }

// ---- state ----
ctl::ControllerQ* g_ctrl;          // points into g_ctrl_storage (no heap)
alignas(ctl::ControllerQ) uint8_t g_ctrl_storage[sizeof(ctl::ControllerQ)];
ctl::OdometryQ* g_idle_odo;        // odometry while no experiment runs
alignas(ctl::OdometryQ) uint8_t g_idle_odo_storage[sizeof(ctl::OdometryQ)];
ctl::ReferenceSpecQ g_ref{ctl::ReferenceSpec{ctl::PathKind::kLine, 1.0f, 0.0f, 0.0f}};

bool g_running;
bool g_drive_mode;                 // the run (or the pending start) is drive mode, not a Start profile
ctl::DriveReferenceQ g_drive;      // drive mode's reference source
ctl::DriveLatch g_latch;           // the last Drive and when it came
int16_t g_v_cmd_mm_s;              // the target the last outer step used (telemetry v_cmd)
int16_t g_w_cmd_mrad_s;
ctl::RefSampleQ g_last_ref;        // the reference of the last outer step (telemetry v_ref)
uint32_t g_ref_t0_us;              // board time of the run's first tick (telemetry ref_t0_us)
bool g_start_pending;              // Start accepted: the next inner tick on time starts the experiment
bool g_start_deferred;             // ...and one late tick has been passed over
uint8_t g_failsafe = proto::kFailsafeNone;
uint32_t g_exp_start_ms;
uint32_t g_exp_duration_ms;
uint32_t g_last_host_us;
uint32_t g_last_inner_us;
uint32_t g_illegal_at_start;
EncSnapshot g_enc;                 // last snapshot (inner or telemetry task)

// unwrapped heading for telemetry
int32_t g_phi_turns;
uint32_t g_phi_last_b32;

proto::Decoder g_rx;
uint16_t g_tx_seq;
uint8_t g_frame[proto::kMaxWire];

// Replies owed to the host (Acks; Params after RequestParams and at boot), kept until the TX
// ring has room for them and sent before any later telemetry frame: periodic telemetry, which
// the next frame supersedes, is what the uplink drops when it is short. 16 replies (6 bytes
// each) cover a burst of 50 back-to-back host frames with room to spare (docs/firmware.md, "XBee
// link"); a reply owed while all 16 wait is lost and counted in tx_drops.
const uint8_t kReplySlots = 16;
proto::ReplyQueue<kReplySlots> g_replies;

template <class T>
T* place(uint8_t* storage, const T& v) {
    T* p = reinterpret_cast<T*>(storage);
    memcpy(storage, &v, sizeof(T));  // trivially copyable value types
    return p;
}

// SetClamp / SetMu / SetController only mark the controller for a rebuild (~16.6 ms of float
// work); app_poll() rebuilds once the receive ring is empty, and a Start rebuilds first. A burst
// of such commands thus costs one rebuild, not one per frame, and while a rebuild runs the
// 256-byte receive ring holds the 191 bytes that arrive at 115200 baud in 16.6 ms.
bool g_rebuild_pending;

// Telemetry's wheel speed references, 100 (v +- b w) / r in 0.01 rad/s, from the kinematic
// loop's v_d (Q12) and omega_d (Q11) in fixed point: k * 2^-shift stands for the factor
// (100 / r, 100 b / r) times 2^-12 or 2^-11, k the largest that fits 16 bits, so that
// |q| * k < 2^31 for every int16 q and no float runs in the telemetry task.
struct RefScale {
    int32_t k;
    uint8_t shift;
};
RefScale g_wref_v, g_wref_w;

RefScale ref_scale(float factor, uint8_t q_bits) {
    int8_t s = 8;
    while (s > -12 && factor * static_cast<float>(1UL << 12) / static_cast<float>(1UL << (12 - s)) > 65535.0f)
        --s;
    float k = factor * static_cast<float>(1UL << 12) / static_cast<float>(1UL << (12 - s));
    return RefScale{static_cast<int32_t>(k + 0.5f), static_cast<uint8_t>(q_bits + s)};
}

int32_t scaled(int16_t q, const RefScale& r) { return (static_cast<int32_t>(q) * r.k) >> r.shift; }

void rebuild_controller() {
    float inv_r = 1.0f / static_cast<float>(g_robot.r);
    g_wref_v = ref_scale(100.0f * inv_r, 12);
    g_wref_w = ref_scale(100.0f * static_cast<float>(g_robot.b) * inv_r, 11);
    // the inner period: the controller's wheel rate for it is precomputed (no division on the
    // first step of an experiment)
    ctl::ControlConfigQ q(make_cfg(), proto::kInnerPeriodUs);
    g_ctrl = place(g_ctrl_storage, ctl::ControllerQ(q));
    g_idle_odo = place(g_idle_odo_storage, ctl::OdometryQ(q.odo));
}

// Queues the frame whole, or drops it and counts it (tx_drops) when the TX ring has no room.
template <class Msg>
void send_msg(const Msg& m) {
    uint16_t n = proto::encode_message(m, g_tx_seq, g_frame, sizeof g_frame);
    if (n != 0 && xbee_write(g_frame, n)) ++g_tx_seq;
}

// A reply: false (nothing built or sent, nothing counted) while the TX ring has no room for it.
template <class Msg>
bool send_reply(const Msg& m) {
    if (xbee_tx_free() < proto::wire_size(Msg::kSize)) return false;
    send_msg(m);  // fits: the main loop is the ring's only producer
    return true;
}

bool send_ack(const proto::Reply& r) {
    proto::Ack a;
    a.cmd_seq = r.cmd_seq;
    a.cmd_type = r.cmd_type;
    a.result = r.result;
    a.detail = r.detail;
    return send_reply(a);
}

// The Params are built when they are sent: they report the configuration in use then (any
// command handled between the RequestParams and this moment included).
bool send_params() {
    if (xbee_tx_free() < proto::wire_size(proto::Params::kSize)) return false;
    proto::Params p;
    p.mu_s = static_cast<float>(g_robot.mu_s);
    p.mu_k = static_cast<float>(g_robot.mu_k);
    p.b = static_cast<float>(g_robot.b);
    p.e = static_cast<float>(g_robot.e);
    p.d = static_cast<float>(g_robot.d);
    p.g = static_cast<float>(g_robot.g);
    p.h = static_cast<float>(g_robot.h);
    p.m_r = static_cast<float>(g_robot.m_r);
    p.I_rz = static_cast<float>(g_robot.I_rz);
    p.I_wz = static_cast<float>(g_robot.I_wz);
    p.I_wy = static_cast<float>(g_robot.I_wy);
    p.r = static_cast<float>(g_robot.r);
    p.m_w = static_cast<float>(g_robot.m_w);
    // the motor the torque->duty map assumes (the datasheet's with the SetModel fit)
    p.supply_v = static_cast<float>(g_motor.supply_v);
    p.no_load_rad_s = static_cast<float>(g_motor.no_load_rad_s);
    p.stall_nm = static_cast<float>(g_motor.stall_nm);
    p.encoder_ppr = ENC_COUNTS_PER_REV;
    p.inner_period_us = proto::kInnerPeriodUs;
    p.outer_period_us = proto::kOuterPeriodUs;
    p.telemetry_period_us = proto::kTelemetryPeriodUs;
    p.baud = proto::kBaud;
    p.clamp_on = g_clamp_on ? 1 : 0;
    p.controller = g_variant == ctl::Variant::kThesis ? proto::kControllerThesis
                                                      : proto::kControllerImproved;
    p.firmware_id = FIRMWARE_ID;
    p.ke_ratio = static_cast<float>(g_motor_fit.ke_ratio);
    p.drop_v = static_cast<float>(g_motor_fit.drop_v);
    return send_reply(p);
}

struct ReplySink {
    bool send(const proto::Reply& r) { return r.kind == proto::Reply::kParams ? send_params() : send_ack(r); }
};

// Sends the replies owed, oldest first, as far as the TX ring takes them; true when none waits.
bool flush_replies() {
    if (g_replies.empty()) return true;
    ReplySink sink;
    return g_replies.flush(sink);
}

void owe_ack(uint16_t seq, uint8_t type, uint8_t result, uint8_t detail) {
    if (!g_replies.ack(seq, type, result, detail)) xbee_count_drop();
    flush_replies();
}

void owe_params() {
    if (!g_replies.params()) xbee_count_drop();
    flush_replies();
}

// Running, or about to (a Start waiting for its tick): commands that change the
// configuration or start an experiment are refused.
bool busy() { return g_running || g_start_pending; }

void stop_motors(uint8_t why) {
    motor_brake();
    if (g_running) {
        // the idle odometry continues from the run's last pose and counts, so telemetry keeps
        // reporting where the robot ended up
        g_idle_odo->reset(g_enc.count_r, g_enc.count_l, g_ctrl->odometry().pose());
    }
    g_running = false;
    g_drive_mode = false;
    g_start_pending = false;
    g_failsafe = why;
}

// ---- commands ----
// Every check happens before anything changes; a rejected command changes nothing.
uint8_t cmd_start(const uint8_t* pl, uint8_t len, uint8_t* detail) {
    proto::Start s = proto::Start();
    if (!s.decode(pl, len)) return proto::kResultBadLength;
    if (busy()) return proto::kResultBusy;
    if (g_rebuild_pending) {  // a SetClamp / SetMu / SetController just before: the run uses it
        g_rebuild_pending = false;
        rebuild_controller();
    }
    float r = static_cast<float>(g_robot.r);
    float t_acc = s.get_accel_time();
    ctl::ReferenceSpec spec = ctl::straight_profile(r, s.get_wheel_accel(), t_acc);
    if (s.profile == proto::kProfileArc) spec.kind = ctl::PathKind::kArc;
    if (s.profile == proto::kProfileFigureEight) spec.kind = ctl::PathKind::kFigureEight;
    spec.radius_m = s.profile == proto::kProfileStraight ? 0.0f : s.get_radius();
    if (!spec.valid()) {
        // which field makes the reference invalid: the radius for paths, else the speed
        *detail = (spec.kind != ctl::PathKind::kLine && !(spec.radius_m >= 0.05f || spec.radius_m <= -0.05f)) ? 4 : 1;
        return proto::kResultOutOfRange;
    }
    ctl::ReferenceSpecQ q(spec);
    if (!q.ok) {
        *detail = 1;
        return proto::kResultOutOfRange;
    }
    // accepted: the experiment starts at the next inner tick (start_experiment(), at most one
    // inner period later, two if that tick is late), so that its first control step comes one
    // period after the reset
    g_ref = q;
    g_exp_duration_ms = s.duration;
    g_drive_mode = false;
    g_start_pending = true;
    g_start_deferred = false;
    return proto::kResultOk;
}

// Drive: the target of drive mode; while idle it also starts drive mode at the next inner tick
// (like a Start, from the origin). busy while a Start profile runs or waits for its tick.
uint8_t cmd_drive(const uint8_t* pl, uint8_t len, uint32_t rx_us) {
    proto::Drive d = proto::Drive();
    d.decode(pl, len);  // length and range checked by validate_command
    if (busy() && !g_drive_mode) return proto::kResultBusy;
    g_latch.received(d.linear, d.angular, rx_us);
    if (busy()) return proto::kResultOk;  // drive mode runs (or starts at the next tick)
    if (g_rebuild_pending) {
        g_rebuild_pending = false;
        rebuild_controller();
    }
    g_drive.reset();
    g_drive_mode = true;
    g_start_pending = true;
    g_start_deferred = false;
    return proto::kResultOk;
}

// SetModel: the fitted geometry and motor. Checked in full before anything changes: the
// ranges (validate_command), then that the controller's fixed-point configuration holds them.
uint8_t cmd_set_model(const uint8_t* pl, uint8_t len, uint8_t* detail) {
    proto::SetModel m = proto::SetModel();
    m.decode(pl, len);  // length and range checked by validate_command
    if (busy()) return proto::kResultBusy;
    slip::RobotParams robot = g_robot;
    robot.r = m.get_r();
    robot.b = m.get_b();
    slip::MotorImperfections fit;
    fit.ke_ratio = m.get_ke_ratio();
    fit.drop_v = m.get_drop_v();
    const slip::MotorParams motor = slip::motor_as_driven(kMotor, fit);
    if (!ctl::ControlConfigQ(make_cfg(robot, motor), proto::kInnerPeriodUs).ok) {
        *detail = 0;
        return proto::kResultOutOfRange;
    }
    g_robot = robot;
    g_motor_fit = fit;
    g_motor = motor;
    g_params_default = false;
    g_rebuild_pending = true;
    return proto::kResultOk;
}

uint8_t cmd_set_drive_limits(const uint8_t* pl, uint8_t len, uint8_t* detail) {
    proto::SetDriveLimits m = proto::SetDriveLimits();
    m.decode(pl, len);  // length and range checked by validate_command
    if (busy()) return proto::kResultBusy;
    const ctl::DriveLimits lim{m.get_accel(), m.get_alpha()};
    const ctl::DriveConfigQ c(lim, proto::kOuterPeriodUs);
    if (!c.ok) {
        *detail = 0;
        return proto::kResultOutOfRange;
    }
    g_drive_cfg = c;
    g_drive_timeout_us = static_cast<uint32_t>(m.cmd_timeout) * 1000UL;  // raw ms
    return proto::kResultOk;
}

// The reference of an outer step: drive mode's from the latched Drive target (0 after the
// command timeout), else the Start profile's at the run's time.
ctl::RefSampleQ next_reference(uint32_t t_ms) {
    if (!g_drive_mode) {
        g_v_cmd_mm_s = g_w_cmd_mrad_s = 0;
        return ctl::reference_at_q(g_ref, t_ms);
    }
    const uint32_t now = time_us();
    g_v_cmd_mm_s = g_latch.v_mm_s(now, g_drive_timeout_us);
    g_w_cmd_mrad_s = g_latch.omega_mrad_s(now, g_drive_timeout_us);
    return g_drive.step(g_drive_cfg, ctl::drive_v_q12(g_v_cmd_mm_s), ctl::drive_omega_q11(g_w_cmd_mrad_s));
}

// At the inner tick after an accepted Start (instead of that tick's idle odometry): the
// controller starts with this tick's encoder snapshot (reset, the outer step with the
// reference at t = 0, the first command from rest, applied at once), and this tick's time
// (already in g_last_inner_us) is the baseline of the next control step's dt, one inner period
// later -- the period the controller's wheel rate is precomputed for, so that step does not
// divide as a dt from the arbitrary moment of the command would make it. The reference's t = 0
// and the duration count from this tick; the outer task restarts in phase with it (next at
// t = 50 ms, then every 50 ms), the schedule lib/closedloop runs.
void start_experiment() {
    g_last_ref = next_reference(0);
    g_ref_t0_us = g_last_inner_us;
    const ctl::InnerOutQ& o = g_ctrl->start(g_enc.count_r, g_enc.count_l, ctl::PoseQ{0, 0, 0}, g_last_ref);
    motor_set_ramp_q15(o.pwm_r_q15, o.slope_r_q15, o.pwm_l_q15, o.slope_l_q15,
                       static_cast<uint8_t>(proto::kInnerPeriodUs / proto::kSchedTickUs - 1u));
    sched_restart_after_current(proto::kTaskOuter);
    g_phi_turns = 0;
    g_phi_last_b32 = 0;
    g_illegal_at_start = g_enc.illegal_l + g_enc.illegal_r;
    g_exp_start_ms = sched_ms();
    g_failsafe = proto::kFailsafeNone;
    g_start_pending = false;
    g_running = true;
    sched_reset_stats();
}

// Handles one verified host frame; returns whether it decoded to a known host message (a
// host-to-robot type with its exact length), the only frames that count as the host being
// alive for the host-timeout failsafe: a stray device or a looping host sending valid frames
// of unknown types, or of a wrong length, must not keep the robot driving.
bool handle_frame(const proto::Frame& f, uint32_t rx_us) {
    uint8_t detail = 255;
    uint8_t res = proto::validate_command(f.type, f.payload, f.len, &detail);
    const bool known = res != proto::kResultUnknownType && res != proto::kResultBadLength;
    if (res == proto::kResultOk) {
        switch (f.type) {
            case proto::kMsgStart:
                res = cmd_start(f.payload, f.len, &detail);
                break;
            case proto::kMsgDrive:
                res = cmd_drive(f.payload, f.len, rx_us);
                break;
            case proto::kMsgSetModel:
                res = cmd_set_model(f.payload, f.len, &detail);
                break;
            case proto::kMsgSetDriveLimits:
                res = cmd_set_drive_limits(f.payload, f.len, &detail);
                break;
            case proto::kMsgStop:
                if (busy() || !motor_braking()) stop_motors(proto::kFailsafeStoppedByHost);
                break;
            case proto::kMsgSetClamp: {
                proto::SetClamp c = proto::SetClamp();
                c.decode(f.payload, f.len);  // length checked by validate_command
                if (busy()) { res = proto::kResultBusy; break; }
                g_clamp_on = c.on != 0;
                g_rebuild_pending = true;
                break;
            }
            case proto::kMsgSetController: {
                proto::SetController c = proto::SetController();
                c.decode(f.payload, f.len);  // length and range checked by validate_command
                if (busy()) { res = proto::kResultBusy; break; }
                g_variant = c.variant == proto::kControllerThesis ? ctl::Variant::kThesis : ctl::Variant::kImproved;
                g_rebuild_pending = true;
                break;
            }
            case proto::kMsgSetMu: {
                proto::SetMu m = proto::SetMu();
                m.decode(f.payload, f.len);  // length checked by validate_command
                if (busy()) { res = proto::kResultBusy; break; }
                g_robot.mu_s = m.get_mu_s();
                g_robot.mu_k = m.get_mu_k();
                g_params_default = false;
                g_rebuild_pending = true;
                break;
            }
            case proto::kMsgRequestParams:
            case proto::kMsgHeartbeat:
            default:
                break;
        }
    }
    owe_ack(f.seq, f.type, res, detail);
    if (res == proto::kResultOk && f.type == proto::kMsgRequestParams) owe_params();
    return known;
}

// ---- tasks ----
void inner_task() {
    g_enc = enc_snapshot();
    uint32_t now_us = time_us();
    uint32_t dt_us = now_us - g_last_inner_us;
    g_last_inner_us = now_us;
    if (g_start_pending) {
        // A tick released late (the main loop was busy, e.g. with this very command) by more
        // than the controller's first-order window would give the first control step, on time,
        // a dt that short of the period: passed over once, the next tick starts.
        if (dt_us <= proto::kInnerPeriodUs + ctl::kRateWindowUs || g_start_deferred) {
            start_experiment();
            return;
        }
        g_start_deferred = true;
    }
    if (!g_running) {
        g_idle_odo->update(g_enc.count_r, g_enc.count_l, dt_us);
        return;
    }
    if (g_enc.illegal_l + g_enc.illegal_r != g_illegal_at_start) {
        stop_motors(proto::kFailsafeEncoderFault);  // counts no longer trustworthy
        return;
    }
    const ctl::InnerOutQ& o = g_ctrl->inner_step(g_enc.count_r, g_enc.count_l, dt_us);
    // the duty at the start of the tick, then its ramp every ms until the next tick
    motor_set_ramp_q15(o.pwm_r_q15, o.slope_r_q15, o.pwm_l_q15, o.slope_l_q15,
                       static_cast<uint8_t>(proto::kInnerPeriodUs / proto::kSchedTickUs - 1u));
    if (!g_drive_mode && sched_ms() - g_exp_start_ms >= g_exp_duration_ms) stop_motors(proto::kFailsafeFinished);
}

void outer_task() {
    if (!g_running) return;
    g_last_ref = next_reference(sched_ms() - g_exp_start_ms);
    g_ctrl->outer_step(g_last_ref);
}

int16_t sat16(int32_t v) {
    return v > 32767 ? 32767 : (v < -32768 ? -32768 : static_cast<int16_t>(v));
}
uint16_t satu16(uint32_t v) { return v > 0xFFFFu ? 0xFFFFu : static_cast<uint16_t>(v); }
// Q-format value -> telemetry raw units: v * num / 2^shift (num <= 10000, shift <= 16),
// saturated to int16. v is clipped first to the range that saturates anyway, so the product
// stays below 2^31 and no 64-bit arithmetic is needed.
template <int32_t NUM, uint8_t SHIFT>
int16_t q_to_raw16(int32_t v) {
    static_assert(NUM > 0 && NUM <= 10000 && SHIFT <= 16, "range of the int32 product");
    const int32_t lim = static_cast<int32_t>((static_cast<uint32_t>(32768) << SHIFT) / NUM) + 1;
    if (v > lim) v = lim;
    if (v < -lim) v = -lim;
    return sat16((v * NUM) >> SHIFT);
}
// Q20 metres -> micrometres (1e6 / 2^20 = 15625 / 16384), split so that it fits int32:
// |x_q20| < 2^31 gives |hi| <= 2^17 and hi * 15625 < 2^31.
int32_t q20_to_um(int32_t v_q20) {
    int32_t hi = v_q20 >> 14;
    int32_t lo = v_q20 & 0x3FFF;
    return hi * 15625 + ((lo * 15625) >> 14);
}

// The stack scan goes on at most this far per frame (about 10 cycles a byte): a stack that grew
// by hundreds of bytes since the last frame (a float rebuild of the configuration) is followed
// over a few frames instead of costing one frame thousands of cycles. Any 8-byte window without
// a used byte ends a scan, so each call either ends or moves the mark down by at least 56 bytes.
const uint16_t kStackScanBytesPerFrame = 64;

void telemetry_task() {
    EncSnapshot e = enc_snapshot();
    uint32_t t_us = time_us();  // right after the snapshot: the frame's time is the counts' time
    const ctl::OdometryQ& odo = g_running ? g_ctrl->odometry() : *g_idle_odo;
    const ctl::InnerOutQ& in = g_ctrl->inner();
    const ctl::KinematicOutQ& kin = g_ctrl->kinematic();
    proto::Telemetry t;
    memset(&t, 0, sizeof t);
    t.t_us = t_us;
    t.enc_r = e.count_r;
    t.enc_l = e.count_l;
    t.omega_r = q_to_raw16<100, 8>(odo.omega_r_q8());
    t.omega_l = q_to_raw16<100, 8>(odo.omega_l_q8());
    if (g_running) {
        // wheel speed references from the kinematic loop's (v_d, omega_d): (v +- b w) / r
        int32_t tv = scaled(kin.v_d_q12, g_wref_v), tw = scaled(kin.omega_d_q11, g_wref_w);
        t.omega_ref_r = sat16(tv + tw);
        t.omega_ref_l = sat16(tv - tw);
        t.tau_cmd_r = q_to_raw16<10000, 16>(in.tau_r_q16);
        t.tau_cmd_l = q_to_raw16<10000, 16>(in.tau_l_q16);
        if (g_clamp_on) {
            int32_t m = in.tau_max_r_q16 < in.tau_max_l_q16 ? in.tau_max_r_q16 : in.tau_max_l_q16;
            t.tau_max = q_to_raw16<10000, 16>(m);
        }
        t.v_ref = q_to_raw16<1000, 12>(g_last_ref.v_q12);
        t.omega_ref = q_to_raw16<1000, 11>(g_last_ref.omega_q11);
        t.v_cmd = g_v_cmd_mm_s;
        t.omega_cmd = g_w_cmd_mrad_s;
    }
    t.ref_t0_us = g_ref_t0_us;
    t.pwm_r = q_to_raw16<10000, 15>(motor_duty_q15(kRight));
    t.pwm_l = q_to_raw16<10000, 15>(motor_duty_q15(kLeft));
    const ctl::PoseQ& p = odo.pose();
    t.x_odo = q20_to_um(p.x_q20);
    t.y_odo = q20_to_um(p.y_q20);
    // unwrap the binary-angle heading: turns + signed fraction, in micro-radians
    int32_t d = static_cast<int32_t>(p.phi_b32 - g_phi_last_b32);
    uint32_t prev = g_phi_last_b32;
    g_phi_last_b32 = p.phi_b32;
    if (d > 0 && p.phi_b32 < prev) ++g_phi_turns;        // crossed 2^32 -> 0 going up
    else if (d < 0 && p.phi_b32 > prev) --g_phi_turns;   // crossed 0 -> 2^32 going down
    // fraction of a turn: float keeps 24 bits, 0.4 urad of resolution
    int32_t frac_urad = static_cast<int32_t>(static_cast<float>(p.phi_b32 >> 8) * (6283185.307f / 16777216.0f));
    int32_t turns = g_phi_turns > 340 ? 340 : (g_phi_turns < -340 ? -340 : g_phi_turns);
    int32_t urad = turns * 6283185L + frac_urad;
    t.phi_odo = urad;
    const TaskStats& si = sched_stats(proto::kTaskInner);
    const TaskStats& so = sched_stats(proto::kTaskOuter);
    const TaskStats& st = sched_stats(proto::kTaskTelemetry);
    t.set_inner_last_cycles(si.last_cycles);
    t.set_inner_max_cycles(si.max_cycles);
    t.inner_overruns = si.overruns;
    t.set_outer_last_cycles(so.last_cycles);
    t.set_outer_max_cycles(so.max_cycles);
    t.outer_overruns = so.overruns;
    t.set_telemetry_last_cycles(st.last_cycles);
    t.set_telemetry_max_cycles(st.max_cycles);
    t.telemetry_overruns = st.overruns;
    t.illegal_r = satu16(e.illegal_r);
    t.illegal_l = satu16(e.illegal_l);
    t.rx_crc_errors = g_rx.crc_errors();
    t.rx_bad_frames = g_rx.bad_frames();
    XbeeCounters xc = xbee_counters();
    t.rx_overflows = xc.rx_overflows;
    t.tx_drops = xc.tx_drops;
    uint8_t status = 0;
    if (g_running) status |= proto::kStatusRunning;
    if (g_clamp_on) status |= proto::kStatusClampOn;
    if (g_failsafe != proto::kFailsafeNone && g_failsafe != proto::kFailsafeFinished &&
        g_failsafe != proto::kFailsafeStoppedByHost)
        status |= proto::kStatusFailsafe;
    if (!motor_braking()) status |= proto::kStatusMotorsEnabled;
    if (g_params_default) status |= proto::kStatusParamsDefault;
    if (g_variant == ctl::Variant::kThesis) status |= proto::kStatusThesisController;
    if (g_running && g_drive_mode) status |= proto::kStatusDriveMode;
    t.status = status;
    t.failsafe = g_failsafe;
    t.reset_cause = boot_reset_cause();
    // the latest pair, started by the 1 kHz tick at most ~1.2 ms ago (sched.cpp): a sample one
    // telemetry period old would lag the duty the inner task changed since
    t.current_r = motor_sense_raw(kRight);
    t.current_l = motor_sense_raw(kLeft);
    t.stack_hwm = stack_high_water(kStackScanBytesPerFrame);
    t.boot_count = boot_count();
    // Replies first: while one waits for room (app_poll() sends it as soon as there is), this
    // frame is dropped and counted. Not flushed here: a Params built in this task would add its
    // encoding to the task's budget.
    if (g_replies.empty()) send_msg(t);
    else xbee_count_drop();
}

}  // namespace

void app_init() {
    rebuild_controller();
    g_enc = enc_snapshot();
    g_idle_odo->reset(g_enc.count_r, g_enc.count_l, ctl::PoseQ{0, 0, 0});
    g_ctrl->reset(g_enc.count_r, g_enc.count_l, ctl::PoseQ{0, 0, 0});
    g_last_inner_us = time_us();
    if (boot_reset_cause() & _BV(WDRF)) g_failsafe = proto::kFailsafeWatchdogReset;
    (void)stack_high_water();  // first scan (the whole stack in use so far) before the schedule
    owe_params();
}

void app_poll() {
    flush_replies();  // what waited for room since the last iteration goes first
    uint8_t b;
    while (xbee_read(&b)) {
        proto::Decoder::Status s = g_rx.feed(b);
        if (s == proto::Decoder::kFrame) {
            uint32_t rx_us = time_us();
            if (handle_frame(g_rx.frame(), rx_us)) g_last_host_us = rx_us;
        } else if (s == proto::Decoder::kError && g_rx.error_has_header()) {
            uint8_t res = g_rx.error() == proto::Decoder::kErrVersion ? proto::kResultBadVersion
                                                                      : proto::kResultBadCrc;
            owe_ack(g_rx.error_seq(), g_rx.error_type(), res, 255);
        }
    }
    if (g_rebuild_pending) {  // the receive ring is empty here
        g_rebuild_pending = false;
        rebuild_controller();
    }
    if (g_running && time_us() - g_last_host_us >= kHostTimeoutUs)
        stop_motors(proto::kFailsafeHostTimeout);
    if (g_fault_hang) {
        for (;;) {
        }
    }
}

const TaskConfig* app_tasks() { return kTasks; }
uint8_t app_task_count() { return sizeof kTasks / sizeof kTasks[0]; }
