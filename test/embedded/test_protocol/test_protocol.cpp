// The frame codec of lib/protocol on the (simulated) ATmega2560: CRC check value, COBS,
// byte-exact frames against golden vectors made by the host's Python codec (so the AVR's
// endianness, float layout and struct packing agree with the host), streaming decode of
// corrupted and truncated input, the generated command validator and saturating setters.
// Unity output on UART0 via test/embedded/unity_config.h.
//
// The golden vectors below are host_tools.protocol output; host_tools/tests/
// test_protocol_generated.py::test_embedded_golden_vectors regenerates them and fails on drift.
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
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

// GOLDEN Telemetry seq=65535
static const uint8_t kGoldenTelemetry[] = {
    0x00, 0x15, 0x04, 0x01, 0xff, 0xff, 0xd8, 0xfe, 0xff, 0xff, 0xc0, 0x1d, 0xfe, 0xff, 0xff, 0xff,
    0xff, 0x7f, 0x51, 0x0e, 0x1e, 0xfb, 0x01, 0x01, 0x01, 0x05, 0xb6, 0x03, 0xec, 0xe1, 0x01, 0x08,
    0x10, 0x27, 0x3c, 0xf6, 0x87, 0xd6, 0x12, 0x08, 0xe0, 0x5e, 0xf8, 0xff, 0xa0, 0x2e, 0x63, 0x06,
    0x03, 0x03, 0xff, 0xff, 0x03, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
    0x01, 0x01, 0x01, 0x02, 0x07, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x06, 0x03, 0x01,
    0x08, 0xff, 0x03, 0x01, 0x13, 0x2c, 0x03, 0x01, 0x02, 0x2c, 0x01, 0x1e, 0xfb, 0x2c, 0x01, 0x1e,
    0xfb, 0x15, 0xcd, 0x5b, 0x07, 0x73, 0x50, 0x00,
};
// GOLDEN Params seq=7
static const uint8_t kGoldenParams[] = {
    0x00, 0x04, 0x04, 0x02, 0x07, 0x1d, 0xb4, 0xc8, 0x76, 0x3e, 0x6a, 0xbc, 0x74, 0x3e, 0x3d, 0x0a,
    0xd7, 0x3d, 0x5c, 0x8f, 0xc2, 0x3d, 0xae, 0x47, 0x61, 0x3d, 0xc3, 0xf5, 0x1c, 0x41, 0x7c, 0xf2,
    0xb0, 0x3c, 0x01, 0x17, 0xc0, 0x3f, 0x0c, 0xcb, 0x1f, 0x3c, 0x94, 0x17, 0x19, 0x3a, 0x94, 0x17,
    0x99, 0x3a, 0x06, 0x81, 0x15, 0x3d, 0x6f, 0x12, 0x83, 0x3d, 0x01, 0x0f, 0x40, 0x41, 0x9a, 0x99,
    0x12, 0x42, 0xb8, 0x1e, 0x45, 0x3f, 0x40, 0x07, 0xa8, 0x61, 0x01, 0x03, 0x50, 0xc3, 0x01, 0x03,
    0x20, 0x4e, 0x01, 0x01, 0x03, 0xc2, 0x01, 0x07, 0x01, 0x01, 0x78, 0x56, 0x34, 0x12, 0x01, 0x03,
    0x80, 0x3f, 0x01, 0x01, 0x01, 0x03, 0x7e, 0x99, 0x00,
};

static Telemetry golden_telemetry() {
    Telemetry t;
    memset(&t, 0, sizeof t);
    t.t_us = 4294967000UL;
    t.enc_r = -123456L;
    t.enc_l = 2147483647L;
    TEST_ASSERT_TRUE(t.set_omega_r(36.65f));
    TEST_ASSERT_TRUE(t.set_omega_l(-12.5f));
    TEST_ASSERT_TRUE(t.set_tau_cmd_r(0.095f));
    TEST_ASSERT_TRUE(t.set_tau_cmd_l(-0.77f));
    TEST_ASSERT_TRUE(t.set_pwm_r(1.0f));
    TEST_ASSERT_TRUE(t.set_pwm_l(-0.25f));
    TEST_ASSERT_TRUE(t.set_x_odo(1.234567f));
    TEST_ASSERT_TRUE(t.set_y_odo(-0.5f));
    TEST_ASSERT_TRUE(t.set_phi_odo(6.5f));
    t.set_inner_last_cycles(12345UL);   // 771 units of 16 cycles
    t.set_inner_max_cycles(2000000UL);  // saturates at 65535
    t.inner_overruns = 3;
    t.illegal_l = 7;
    t.status = kStatusRunning | kStatusClampOn;
    t.failsafe = kFailsafeHostTimeout;
    t.reset_cause = kResetCauseWatchdog;
    t.current_r = 1023;
    t.stack_hwm = 812;
    t.boot_count = 513;
    TEST_ASSERT_TRUE(t.set_v_ref(0.3f));
    TEST_ASSERT_TRUE(t.set_omega_ref(-1.25f));
    t.v_cmd = 300;
    t.omega_cmd = -1250;
    t.ref_t0_us = 123456789UL;
    return t;
}

static void test_crc_check_value() {
    const uint8_t s[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
    TEST_ASSERT_EQUAL_HEX16(0x29B1, crc16(s, 9));
}

static void test_cobs_vectors() {
    const uint8_t in[] = {0x11, 0x22, 0x00, 0x33};
    const uint8_t want[] = {0x03, 0x11, 0x22, 0x02, 0x33};
    uint8_t enc[8], dec[8];
    TEST_ASSERT_EQUAL_UINT16(5, cobs_encode(in, 4, enc, sizeof enc));
    TEST_ASSERT_EQUAL_HEX8_ARRAY(want, enc, 5);
    TEST_ASSERT_EQUAL_INT16(4, cobs_decode(enc, 5, dec, sizeof dec));
    TEST_ASSERT_EQUAL_HEX8_ARRAY(in, dec, 4);
}

static void test_telemetry_matches_host_golden() {
    Telemetry t = golden_telemetry();
    uint8_t wire[kMaxWire];
    uint16_t n = encode_message(t, 65535u, wire, sizeof wire);
    TEST_ASSERT_EQUAL_UINT16(sizeof kGoldenTelemetry, n);
    TEST_ASSERT_EQUAL_HEX8_ARRAY(kGoldenTelemetry, wire, n);
}

static void test_params_floats_match_host_golden() {
    Params p;
    // the parameter table's values, as the firmware reports them
#define SET_FROM_TABLE(name, value, lo, hi, unit, run_format) p.name = static_cast<float>(slip::table::name);
    SLIP_ROBOT_PARAMS(SET_FROM_TABLE)
#undef SET_FROM_TABLE
    p.supply_v = static_cast<float>(slip::table::supply_v);
    p.no_load_rad_s = static_cast<float>(slip::table::no_load_rad_s);
    p.stall_nm = static_cast<float>(slip::table::stall_nm);
    p.encoder_ppr = SLIP_ENCODER_COUNTS_PER_REV; p.inner_period_us = 25000UL; p.outer_period_us = 50000UL;
    p.telemetry_period_us = 20000UL; p.baud = 115200UL; p.clamp_on = 1; p.controller = kControllerThesis;
    p.firmware_id = 0x12345678UL;
    p.ke_ratio = 1.0f;
    p.drop_v = 0.0f;
    uint8_t wire[kMaxWire];
    uint16_t n = encode_message(p, 7, wire, sizeof wire);
    TEST_ASSERT_EQUAL_UINT16(sizeof kGoldenParams, n);
    TEST_ASSERT_EQUAL_HEX8_ARRAY(kGoldenParams, wire, n);
}

static void test_decode_golden_byte_by_byte() {
    Decoder d;
    int frames = 0;
    for (uint16_t i = 0; i < sizeof kGoldenTelemetry; ++i)
        if (d.feed(kGoldenTelemetry[i]) == Decoder::kFrame) ++frames;
    TEST_ASSERT_EQUAL_INT(1, frames);
    Telemetry u;
    TEST_ASSERT_TRUE(u.decode(d.frame().payload, d.frame().len));
    TEST_ASSERT_EQUAL_UINT16(65535u, d.frame().seq);
    TEST_ASSERT_EQUAL_UINT32(4294967000UL, u.t_us);
    TEST_ASSERT_EQUAL_INT32(-123456L, u.enc_r);
    TEST_ASSERT_FLOAT_WITHIN(0.005f, 36.65f, u.get_omega_r());
    TEST_ASSERT_FLOAT_WITHIN(0.000001f, 1.234567f, u.get_x_odo());
    TEST_ASSERT_EQUAL_UINT32(12336UL, u.get_inner_last_cycles());
}

// Every single-bit flip of the golden frame is rejected, and the following intact frame is
// still received (resync at its leading delimiter).
static void test_bit_flips_rejected_and_resync() {
    uint8_t bad[sizeof kGoldenTelemetry];
    uint16_t accepted_wrong = 0, recovered = 0;
    for (uint16_t pos = 1; pos + 1 < sizeof bad; ++pos) {
        for (uint8_t bit = 0; bit < 8; ++bit) {
            memcpy(bad, kGoldenTelemetry, sizeof bad);
            bad[pos] ^= static_cast<uint8_t>(1u << bit);
            Decoder d;
            for (uint16_t i = 0; i < sizeof bad; ++i)
                if (d.feed(bad[i]) == Decoder::kFrame) ++accepted_wrong;
            for (uint16_t i = 0; i < sizeof kGoldenTelemetry; ++i)
                if (d.feed(kGoldenTelemetry[i]) == Decoder::kFrame && d.frame().seq == 65535u) ++recovered;
        }
    }
    TEST_ASSERT_EQUAL_UINT16(0, accepted_wrong);
    TEST_ASSERT_EQUAL_UINT16((sizeof kGoldenTelemetry - 2) * 8, recovered);
}

static void test_truncated_and_overlong() {
    Decoder d;
    for (uint16_t i = 0; i < 40; ++i) d.feed(kGoldenTelemetry[i]);  // power lost mid-frame
    int frames = 0;
    for (uint16_t i = 0; i < sizeof kGoldenTelemetry; ++i)
        if (d.feed(kGoldenTelemetry[i]) == Decoder::kFrame) ++frames;
    TEST_ASSERT_EQUAL_INT(1, frames);
    TEST_ASSERT_EQUAL_UINT16(1, d.crc_errors() + d.bad_frames());
    for (uint16_t i = 0; i < 300; ++i) d.feed(0x55);
    TEST_ASSERT_EQUAL(Decoder::kError, d.feed(0));
    TEST_ASSERT_EQUAL(Decoder::kErrTooLong, d.error());
}

static void test_command_validation_on_avr() {
    uint8_t wire[kMaxWire], detail = 0;
    Start s;
    s.profile = kProfileFigureEight;
    TEST_ASSERT_TRUE(s.set_wheel_accel(72.0f));
    TEST_ASSERT_TRUE(s.set_accel_time(0.5f));
    TEST_ASSERT_TRUE(s.set_duration(10.0f));
    TEST_ASSERT_TRUE(s.set_radius(-0.4f));
    uint16_t n = encode_message(s, 3, wire, sizeof wire);
    Decoder d;
    Decoder::Status st = Decoder::kNone;
    for (uint16_t i = 0; i < n; ++i) st = d.feed(wire[i]) == Decoder::kFrame ? Decoder::kFrame : st;
    TEST_ASSERT_EQUAL(Decoder::kFrame, st);
    TEST_ASSERT_EQUAL(kResultOk, validate_command(d.frame().type, d.frame().payload, d.frame().len, &detail));
    s.duration = 60001;  // 60.001 s > 60 s
    TEST_ASSERT_EQUAL(kResultOutOfRange, s.validate(&detail));
    TEST_ASSERT_EQUAL_UINT8(3, detail);
    TEST_ASSERT_EQUAL(kResultBadLength, validate_command(kMsgSetMu, wire, 3, &detail));
    TEST_ASSERT_EQUAL(kResultUnknownType, validate_command(200, wire, 0, &detail));
}

static void test_saturation_on_avr_float() {
    Telemetry t;
    TEST_ASSERT_FALSE(t.set_omega_r(NAN));
    TEST_ASSERT_EQUAL_INT16(0, t.omega_r);
    TEST_ASSERT_FALSE(t.set_tau_cmd_r(5.0f));
    TEST_ASSERT_EQUAL_INT16(32767, t.tau_cmd_r);
    TEST_ASSERT_FALSE(t.set_x_odo(-1e6f));
    TEST_ASSERT_EQUAL_INT32(-2147483647L - 1, t.x_odo);
    TEST_ASSERT_FALSE(t.set_phi_odo(INFINITY));
    TEST_ASSERT_EQUAL_INT32(2147483647L, t.phi_odo);
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_crc_check_value);
    RUN_TEST(test_cobs_vectors);
    RUN_TEST(test_telemetry_matches_host_golden);
    RUN_TEST(test_params_floats_match_host_golden);
    RUN_TEST(test_decode_golden_byte_by_byte);
    RUN_TEST(test_bit_flips_rejected_and_resync);
    RUN_TEST(test_truncated_and_overlong);
    RUN_TEST(test_command_validation_on_avr);
    RUN_TEST(test_saturation_on_avr_float);
    UNITY_END();
    cli();
    sleep_cpu();
    return 0;
}
