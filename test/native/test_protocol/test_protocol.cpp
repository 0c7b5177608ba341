// Native Unity tests of lib/protocol: CRC, COBS, frame round trips, corrupted and truncated
// frames, the generated messages and the table-driven command validator.
#include <math.h>
#include <string.h>
#include <unity.h>

#include <protocol/cobs.h>
#include <protocol/crc16.h>
#include <protocol/frame.h>
#include <protocol/messages.h>
#include <slipmodel/params_table.h>

using namespace proto;

void setUp() {}
void tearDown() {}

static Telemetry sample_telemetry() {
    Telemetry t;
    memset(&t, 0, sizeof t);
    t.t_us = 4294967000UL;
    t.enc_r = -123456;
    t.enc_l = 2147483647L;
    t.set_omega_r(36.65f);
    t.set_omega_l(-12.5f);
    t.set_tau_cmd_r(0.095f);
    t.set_tau_cmd_l(-0.77f);
    t.set_pwm_r(1.0f);
    t.set_pwm_l(-0.25f);
    t.set_x_odo(1.234567f);
    t.set_y_odo(-0.5f);
    t.set_phi_odo(6.5f);
    t.set_inner_last_cycles(12345);
    t.set_inner_max_cycles(2000000);  // saturates at 65535 * 16
    t.inner_overruns = 3;
    t.illegal_l = 7;
    t.status = kStatusRunning | kStatusClampOn;
    t.failsafe = kFailsafeHostTimeout;
    t.reset_cause = kResetCauseWatchdog;
    t.current_r = 1023;
    t.stack_hwm = 812;
    return t;
}

// Feeds bytes; returns the number of verified frames and copies the last one.
static int feed_all(Decoder& d, const uint8_t* p, uint16_t n, uint8_t* last_payload = 0, Frame* last = 0) {
    int frames = 0;
    for (uint16_t i = 0; i < n; ++i) {
        if (d.feed(p[i]) == Decoder::kFrame) {
            ++frames;
            if (last) *last = d.frame();
            if (last_payload) memcpy(last_payload, d.frame().payload, d.frame().len);
        }
    }
    return frames;
}

void test_crc_check_value() {
    const uint8_t s[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
    TEST_ASSERT_EQUAL_HEX16(0x29B1, crc16(s, 9));
    TEST_ASSERT_EQUAL_HEX16(0xFFFF, crc16(s, 0));
}

void test_cobs_known_vectors() {
    struct V { uint8_t in[6]; uint8_t n; uint8_t out[7]; uint8_t m; };
    const V v[] = {
        {{0x00}, 1, {0x01, 0x01}, 2},
        {{0x00, 0x00}, 2, {0x01, 0x01, 0x01}, 3},
        {{0x11, 0x22, 0x00, 0x33}, 4, {0x03, 0x11, 0x22, 0x02, 0x33}, 5},
        {{0x11, 0x22, 0x33, 0x44}, 4, {0x05, 0x11, 0x22, 0x33, 0x44}, 5},
        {{0x11, 0x00, 0x00, 0x00}, 4, {0x02, 0x11, 0x01, 0x01, 0x01}, 5},
    };
    for (unsigned k = 0; k < sizeof v / sizeof v[0]; ++k) {
        uint8_t enc[16], dec[16];
        uint16_t m = cobs_encode(v[k].in, v[k].n, enc, sizeof enc);
        TEST_ASSERT_EQUAL_UINT16(v[k].m, m);
        TEST_ASSERT_EQUAL_HEX8_ARRAY(v[k].out, enc, m);
        TEST_ASSERT_EQUAL_INT16(v[k].n, cobs_decode(enc, m, dec, sizeof dec));
        TEST_ASSERT_EQUAL_HEX8_ARRAY(v[k].in, dec, v[k].n);
    }
}

void test_cobs_long_blocks_and_limits() {
    uint8_t in[600], enc[620], dec[600];
    for (uint16_t len = 0; len <= 600; len = static_cast<uint16_t>(len + 1 + len / 7)) {
        for (uint16_t i = 0; i < len; ++i) in[i] = static_cast<uint8_t>((i * 37u + len) % 251u + 1u);
        if (len > 3) in[len / 3] = 0;  // one zero somewhere
        uint16_t m = cobs_encode(in, len, enc, sizeof enc);
        TEST_ASSERT_TRUE(m > 0 && m <= cobs_max_encoded(len));
        for (uint16_t i = 0; i < m; ++i) TEST_ASSERT_NOT_EQUAL(0, enc[i]);
        TEST_ASSERT_EQUAL_INT16(len, cobs_decode(enc, m, dec, sizeof dec));
        if (len) TEST_ASSERT_EQUAL_MEMORY(in, dec, len);
    }
    // Too small an output buffer is refused, never overrun.
    TEST_ASSERT_EQUAL_UINT16(0, cobs_encode(in, 10, enc, 10));
    uint16_t m = cobs_encode(in, 10, enc, sizeof enc);
    TEST_ASSERT_EQUAL_INT16(-1, cobs_decode(enc, m, dec, 5));
    // A code that runs past the end (truncation) and an embedded zero are invalid.
    const uint8_t bad1[] = {0x05, 0x11, 0x22};
    const uint8_t bad2[] = {0x03, 0x11, 0x00};
    TEST_ASSERT_EQUAL_INT16(-1, cobs_decode(bad1, 3, dec, sizeof dec));
    TEST_ASSERT_EQUAL_INT16(-1, cobs_decode(bad2, 3, dec, sizeof dec));
}

void test_telemetry_round_trip() {
    Telemetry t = sample_telemetry();
    uint8_t wire[kMaxWire];
    uint16_t n = encode_message(t, 65535u, wire, sizeof wire);
    TEST_ASSERT_EQUAL_UINT16(wire_size(Telemetry::kSize), n);
    TEST_ASSERT_EQUAL_HEX8(0, wire[0]);
    TEST_ASSERT_EQUAL_HEX8(0, wire[n - 1]);
    for (uint16_t i = 1; i + 1 < n; ++i) TEST_ASSERT_NOT_EQUAL(0, wire[i]);

    Decoder d;
    uint8_t payload[kMaxPayload];
    Frame f = {};  // stays zero if feed_all finds no frame
    TEST_ASSERT_EQUAL_INT(1, feed_all(d, wire, n, payload, &f));
    TEST_ASSERT_EQUAL_UINT8(kMsgTelemetry, f.type);
    TEST_ASSERT_EQUAL_UINT16(65535u, f.seq);
    TEST_ASSERT_EQUAL_UINT8(kVersion, f.version);
    Telemetry u;
    TEST_ASSERT_TRUE(u.decode(payload, f.len));
    uint8_t a[Telemetry::kSize], b[Telemetry::kSize];
    t.encode(a);
    u.encode(b);
    TEST_ASSERT_EQUAL_HEX8_ARRAY(a, b, Telemetry::kSize);
    TEST_ASSERT_EQUAL_UINT32(4294967000UL, u.t_us);
    TEST_ASSERT_EQUAL_INT32(2147483647L, u.enc_l);
    TEST_ASSERT_FLOAT_WITHIN(0.005f, 36.65f, u.get_omega_r());
    TEST_ASSERT_FLOAT_WITHIN(0.00005f, -0.77f, u.get_tau_cmd_l());
    TEST_ASSERT_FLOAT_WITHIN(0.0000005f, 1.234567f, u.get_x_odo());
    TEST_ASSERT_EQUAL_UINT32(12336UL, u.get_inner_last_cycles());  // 12345 / 16 * 16
    TEST_ASSERT_EQUAL_UINT16(65535u, u.inner_max);
    TEST_ASSERT_EQUAL_UINT16(1, d.frames_ok());
    TEST_ASSERT_EQUAL_UINT16(0, d.crc_errors());
}

void test_every_message_type_and_payload_length() {
    Decoder d;
    uint8_t payload[kMaxPayload], got[kMaxPayload], wire[kMaxWire];
    for (uint16_t len = 0; len <= kMaxPayload; ++len) {
        for (uint16_t i = 0; i < len; ++i) payload[i] = static_cast<uint8_t>(i % 3 == 0 ? 0 : i * 7 + len);
        uint16_t n = encode_frame(static_cast<uint8_t>(len), static_cast<uint16_t>(len * 1000u), payload,
                                  static_cast<uint8_t>(len), wire, sizeof wire);
        TEST_ASSERT_EQUAL_UINT16(wire_size(static_cast<uint8_t>(len)), n);
        Frame f = {};  // stays zero if feed_all finds no frame
        TEST_ASSERT_EQUAL_INT(1, feed_all(d, wire, n, got, &f));
        TEST_ASSERT_EQUAL_UINT8(len, f.len);
        TEST_ASSERT_EQUAL_UINT16(len * 1000u, f.seq);
        if (len) TEST_ASSERT_EQUAL_MEMORY(payload, got, len);
    }
    // Payloads above kMaxPayload and too small buffers are refused.
    uint8_t big[kMaxPayload + 1] = {0};
    TEST_ASSERT_EQUAL_UINT16(0, encode_frame(1, 0, big, kMaxPayload + 1, wire, sizeof wire));
    TEST_ASSERT_EQUAL_UINT16(0, encode_frame(1, 0, big, 10, wire, wire_size(10) - 1));
    // Every generated message type has the size the decoder expects.
    TEST_ASSERT_EQUAL_INT16(Telemetry::kSize, payload_size(kMsgTelemetry));
    TEST_ASSERT_EQUAL_INT16(Params::kSize, payload_size(kMsgParams));
    TEST_ASSERT_EQUAL_INT16(0, payload_size(kMsgHeartbeat));
    TEST_ASSERT_EQUAL_INT16(-1, payload_size(0));
}

// Every single-bit flip and every single-byte substitution inside a telemetry frame: the
// decoder must never return a frame that differs from the one sent.
void test_single_corruptions_never_accepted() {
    Telemetry t = sample_telemetry();
    uint8_t wire[kMaxWire], bad[kMaxWire], good_payload[Telemetry::kSize];
    uint16_t n = encode_message(t, 42, wire, sizeof wire);
    t.encode(good_payload);
    long accepted_wrong = 0, rejected = 0;
    for (uint16_t pos = 1; pos + 1 < n; ++pos) {
        for (uint16_t v = 0; v < 256; ++v) {
            if (v == wire[pos]) continue;
            memcpy(bad, wire, n);
            bad[pos] = static_cast<uint8_t>(v);
            Decoder d;
            for (uint16_t i = 0; i < n; ++i) {
                Decoder::Status s = d.feed(bad[i]);
                if (s == Decoder::kFrame) {
                    if (d.frame().len != Telemetry::kSize || d.frame().seq != 42 ||
                        memcmp(d.frame().payload, good_payload, Telemetry::kSize) != 0)
                        ++accepted_wrong;
                } else if (s == Decoder::kError) {
                    ++rejected;
                }
            }
        }
    }
    TEST_ASSERT_EQUAL(0, accepted_wrong);
    TEST_ASSERT_TRUE(rejected >= (long)(n - 2) * 255);
}

void test_truncated_frame_then_resync() {
    Telemetry t = sample_telemetry();
    uint8_t wire[kMaxWire];
    uint16_t n = encode_message(t, 7, wire, sizeof wire);
    for (uint16_t cut = 1; cut < n - 1; ++cut) {
        Decoder d;
        // The first `cut` bytes, as if the robot lost power mid-frame (no trailing delimiter).
        int frames = feed_all(d, wire, cut);
        frames += feed_all(d, wire, n);  // the next frame, with its leading delimiter
        TEST_ASSERT_EQUAL_INT(1, frames);
        TEST_ASSERT_EQUAL_UINT16(7, d.frame().seq);
        TEST_ASSERT_EQUAL_UINT16(cut > 1 ? 1 : 0, d.crc_errors() + d.bad_frames());
    }
    // A frame with bytes dropped in the middle is rejected.
    uint8_t cut[kMaxWire];
    memcpy(cut, wire, 20);
    memcpy(cut + 20, wire + 25, n - 25);
    Decoder d;
    TEST_ASSERT_EQUAL_INT(0, feed_all(d, cut, static_cast<uint16_t>(n - 5)));
    TEST_ASSERT_EQUAL_UINT16(1, d.crc_errors() + d.bad_frames());
}

void test_garbage_overflow_and_short_blocks() {
    Decoder d;
    uint8_t junk[400];
    for (uint16_t i = 0; i < sizeof junk; ++i) junk[i] = static_cast<uint8_t>(i % 255 + 1);
    TEST_ASSERT_EQUAL_INT(0, feed_all(d, junk, sizeof junk));
    TEST_ASSERT_EQUAL(Decoder::kError, d.feed(0));
    TEST_ASSERT_EQUAL(Decoder::kErrTooLong, d.error());
    const uint8_t shorty[] = {0, 0x03, 0x01, 0x01, 0};
    TEST_ASSERT_EQUAL_INT(0, feed_all(d, shorty, sizeof shorty));
    TEST_ASSERT_EQUAL(Decoder::kErrTooShort, d.error());
    uint8_t wire[kMaxWire];
    uint16_t n = encode_frame(kMsgHeartbeat, 9, 0, 0, wire, sizeof wire);
    TEST_ASSERT_EQUAL_INT(1, feed_all(d, wire, n));
    TEST_ASSERT_EQUAL_UINT16(2, d.bad_frames());
}

void test_crc_error_reports_header_and_version_error() {
    uint8_t wire[kMaxWire];
    SetClamp c;
    c.on = 1;
    uint16_t n = encode_message(c, 300, wire, sizeof wire);
    wire[n - 3] ^= 0x01;  // first CRC byte (this body holds no 0x00, so no COBS code there)
    if (wire[n - 3] == 0) wire[n - 3] = 0x55;  // must not become a delimiter
    Decoder d;
    TEST_ASSERT_EQUAL_INT(0, feed_all(d, wire, n));
    TEST_ASSERT_EQUAL(Decoder::kErrCrc, d.error());
    TEST_ASSERT_TRUE(d.error_has_header());
    TEST_ASSERT_EQUAL_UINT8(kMsgSetClamp, d.error_type());
    TEST_ASSERT_EQUAL_UINT16(300, d.error_seq());
    TEST_ASSERT_EQUAL_UINT16(1, d.crc_errors());

    // Intact frame with another version: rebuilt by hand with a valid CRC.
    uint8_t body[7] = {static_cast<uint8_t>(kVersion + 1), kMsgSetClamp, 0x2C, 0x01, 1, 0, 0};
    uint16_t crc = crc16(body, 5);
    body[5] = static_cast<uint8_t>(crc);
    body[6] = static_cast<uint8_t>(crc >> 8);
    wire[0] = 0;
    uint16_t m = cobs_encode(body, 7, wire + 1, sizeof wire - 2);
    wire[m + 1] = 0;
    TEST_ASSERT_EQUAL_INT(0, feed_all(d, wire, static_cast<uint16_t>(m + 2)));
    TEST_ASSERT_EQUAL(Decoder::kErrVersion, d.error());
    TEST_ASSERT_EQUAL_UINT16(300, d.error_seq());
}

void test_counters_saturate() {
    Decoder d;
    const uint8_t junk[] = {0x05, 0x11, 0};  // invalid COBS block
    for (uint32_t i = 0; i < 70000UL; ++i) feed_all(d, junk, 3);
    TEST_ASSERT_EQUAL_UINT16(65535u, d.bad_frames());
}

void test_validate_command() {
    uint8_t detail = 0;
    Start s;
    s.profile = kProfileStraight;
    TEST_ASSERT_TRUE(s.set_wheel_accel(48.0f));
    TEST_ASSERT_TRUE(s.set_accel_time(0.5f));
    TEST_ASSERT_TRUE(s.set_duration(3.0f));
    TEST_ASSERT_TRUE(s.set_radius(0.0f));
    TEST_ASSERT_EQUAL(kResultOk, s.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(255, detail);
    uint8_t p[Start::kSize];
    s.encode(p);
    TEST_ASSERT_EQUAL(kResultOk, validate_command(kMsgStart, p, Start::kSize, &detail));
    TEST_ASSERT_EQUAL(kResultBadLength, validate_command(kMsgStart, p, Start::kSize - 1, &detail));
    TEST_ASSERT_EQUAL(kResultUnknownType, validate_command(kMsgTelemetry, p, 0, &detail));
    TEST_ASSERT_EQUAL(kResultUnknownType, validate_command(99, p, 0, &detail));
    TEST_ASSERT_EQUAL(kResultOk, validate_command(kMsgHeartbeat, p, 0, &detail));

    Start bad = s;
    bad.profile = 3;
    TEST_ASSERT_EQUAL(kResultOutOfRange, bad.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(0, detail);
    bad = s;
    bad.wheel_accel = 20001;  // 200.01 rad/s^2
    TEST_ASSERT_EQUAL(kResultOutOfRange, bad.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(1, detail);
    bad = s;
    bad.wheel_accel = 0;
    TEST_ASSERT_EQUAL(kResultOutOfRange, bad.validate(&detail));
    bad = s;
    bad.set_accel_time(4.0f);  // > duration: constraint accel_time <= duration
    TEST_ASSERT_EQUAL(kResultOutOfRange, bad.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(2, detail);
    bad = s;
    bad.radius = -5001;
    TEST_ASSERT_EQUAL(kResultOutOfRange, bad.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(4, detail);

    SetMu mu;
    mu.set_mu_s(static_cast<float>(slip::table::mu_s));
    mu.set_mu_k(static_cast<float>(slip::table::mu_k));
    TEST_ASSERT_EQUAL(kResultOk, mu.validate(&detail));
    mu.set_mu_k(0.3f);  // mu_k > mu_s
    TEST_ASSERT_EQUAL(kResultOutOfRange, mu.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(1, detail);
    SetClamp c;
    c.on = 2;
    TEST_ASSERT_EQUAL(kResultOutOfRange, c.validate(&detail));
}

void test_saturating_setters() {
    Telemetry t;
    TEST_ASSERT_FALSE(t.set_omega_r(NAN));
    TEST_ASSERT_EQUAL_INT16(0, t.omega_r);
    TEST_ASSERT_FALSE(t.set_omega_r(1000.0f));
    TEST_ASSERT_EQUAL_INT16(32767, t.omega_r);
    TEST_ASSERT_FALSE(t.set_omega_r(-INFINITY));
    TEST_ASSERT_EQUAL_INT16(-32768, t.omega_r);
    TEST_ASSERT_TRUE(t.set_omega_r(-0.005f));  // rounds half away from zero
    TEST_ASSERT_EQUAL_INT16(-1, t.omega_r);
    TEST_ASSERT_FALSE(t.set_x_odo(5000.0f));
    TEST_ASSERT_EQUAL_INT32(2147483647L, t.x_odo);
    TEST_ASSERT_FALSE(t.set_x_odo(-5000.0f));
    TEST_ASSERT_EQUAL_INT32(-2147483647L - 1, t.x_odo);
    TEST_ASSERT_FALSE(t.set_current_r(-1.0f));
    TEST_ASSERT_EQUAL_UINT16(0, t.current_r);
    t.set_telemetry_last_cycles(0xFFFFFFFFUL);
    TEST_ASSERT_EQUAL_UINT16(65535u, t.telemetry_last);
}

void test_task_table() {
    TEST_ASSERT_EQUAL_UINT32(25000UL, task_period_us(kTaskInner));
    TEST_ASSERT_EQUAL_UINT32(50000UL, task_period_us(kTaskOuter));
    TEST_ASSERT_EQUAL_UINT32(20000UL, task_period_us(kTaskTelemetry));
    for (uint8_t i = 0; i < kTaskCount; ++i) {
        // a budget is a positive number of cycles that fits within the task's period
        TEST_ASSERT_TRUE(task_budget_cycles(i) > 0);
        TEST_ASSERT_TRUE(task_budget_cycles(i) < task_period_us(i) * (kFcpuHz / 1000000UL));
    }
    TEST_ASSERT_EQUAL_UINT32(0, task_period_us(kTaskCount));
}

// Deterministic random fuzz: streams of valid frames with random edits (bit flips, byte
// substitutions, deletions, insertions, duplicated spans). Nothing may crash or overrun, and
// every frame the decoder returns must be byte-identical to one that was sent.
static uint32_t rng_state = 0x12345678u;
static uint32_t rnd() {
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 17;
    rng_state ^= rng_state << 5;
    return rng_state;
}

void test_random_corruption_fuzz() {
    static uint8_t sent[8][kMaxWire];
    static uint16_t sent_n[8];
    static uint8_t stream[2048], edited[2600];
    long accepted = 0, accepted_wrong = 0;
    for (int iter = 0; iter < 20000; ++iter) {
        uint16_t n = 0;
        int frames = 1 + static_cast<int>(rnd() % 8);
        for (int k = 0; k < frames; ++k) {
            uint8_t payload[kMaxPayload];
            uint8_t len = static_cast<uint8_t>(rnd() % (kMaxPayload + 1));
            for (uint8_t i = 0; i < len; ++i) payload[i] = static_cast<uint8_t>(rnd() % 3 == 0 ? 0 : rnd());
            sent_n[k] = encode_frame(static_cast<uint8_t>(rnd()), static_cast<uint16_t>(rnd()), payload, len,
                                     sent[k], kMaxWire);
            memcpy(stream + n, sent[k], sent_n[k]);
            n = static_cast<uint16_t>(n + sent_n[k]);
        }
        uint16_t m = n;
        memcpy(edited, stream, n);
        int edits = static_cast<int>(rnd() % 6);
        for (int e = 0; e < edits && m > 0; ++e) {
            uint16_t at = static_cast<uint16_t>(rnd() % m);
            switch (rnd() % 5) {
                case 0: edited[at] ^= static_cast<uint8_t>(1u << (rnd() % 8)); break;
                case 1: edited[at] = static_cast<uint8_t>(rnd()); break;
                case 2: {  // delete up to 30 bytes
                    uint16_t k = static_cast<uint16_t>(1 + rnd() % 30);
                    if (at + k > m) k = static_cast<uint16_t>(m - at);
                    memmove(edited + at, edited + at + k, m - at - k);
                    m = static_cast<uint16_t>(m - k);
                    break;
                }
                case 3: {  // insert up to 40 random bytes
                    uint16_t k = static_cast<uint16_t>(1 + rnd() % 40);
                    if (m + k > sizeof edited) break;
                    memmove(edited + at + k, edited + at, m - at);
                    for (uint16_t i = 0; i < k; ++i) edited[at + i] = static_cast<uint8_t>(rnd());
                    m = static_cast<uint16_t>(m + k);
                    break;
                }
                default: {  // duplicate a span of up to 120 bytes
                    uint16_t k = static_cast<uint16_t>(1 + rnd() % 120);
                    if (at + k > m) k = static_cast<uint16_t>(m - at);
                    if (m + k > sizeof edited) break;
                    memmove(edited + at + k, edited + at, m - at);
                    m = static_cast<uint16_t>(m + k);
                    break;
                }
            }
        }
        Decoder d;
        for (uint16_t i = 0; i < m; ++i) {
            if (d.feed(edited[i]) != Decoder::kFrame) continue;
            ++accepted;
            uint8_t again[kMaxWire];
            const Frame& f = d.frame();
            uint16_t w = encode_frame(f.type, f.seq, f.payload, f.len, again, sizeof again);
            bool found = false;
            for (int k = 0; k < frames && !found; ++k)
                found = w == sent_n[k] && memcmp(again, sent[k], w) == 0;
            if (!found) ++accepted_wrong;
        }
    }
    TEST_ASSERT_EQUAL(0, accepted_wrong);
    TEST_ASSERT_TRUE(accepted > 20000);  // most frames survive: the test does exercise acceptance
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_crc_check_value);
    RUN_TEST(test_cobs_known_vectors);
    RUN_TEST(test_cobs_long_blocks_and_limits);
    RUN_TEST(test_telemetry_round_trip);
    RUN_TEST(test_every_message_type_and_payload_length);
    RUN_TEST(test_single_corruptions_never_accepted);
    RUN_TEST(test_truncated_frame_then_resync);
    RUN_TEST(test_garbage_overflow_and_short_blocks);
    RUN_TEST(test_crc_error_reports_header_and_version_error);
    RUN_TEST(test_counters_saturate);
    RUN_TEST(test_validate_command);
    RUN_TEST(test_saturating_setters);
    RUN_TEST(test_task_table);
    RUN_TEST(test_random_corruption_fuzz);
    return UNITY_END();
}
