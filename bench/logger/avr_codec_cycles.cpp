// Benchmark (prints figures, asserts nothing): CPU cycles of the lib/protocol codec on the
// ATmega2560 (16 MHz), measured with Timer1 at clk/1 in simavr. Output on UART0.
//   bash bench/logger/avr_codec_cycles.sh
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdio.h>
#include <string.h>

#include <protocol/crc16.h>
#include <protocol/frame.h>
#include <protocol/messages.h>

using namespace proto;

static int uart_putc(char c, FILE*) {
    while (!(UCSR0A & (1 << UDRE0))) {
    }
    UDR0 = static_cast<uint8_t>(c);
    return 0;
}
static FILE uart_out;

static inline void t_start() {
    TCCR1B = 0;
    TCNT1 = 0;
    TIFR1 = 1 << TOV1;
    TCCR1B = 1 << CS10;  // clk/1
}
static inline uint16_t t_stop() {
    uint16_t t = TCNT1;
    TCCR1B = 0;
    return t;
}
// Overhead of t_start/t_stop themselves, subtracted from every figure.
static uint16_t overhead() {
    t_start();
    return t_stop();
}

static volatile float g_in[8] = {36.65f, -12.5f, 0.095f, -0.77f, 1.0f, -0.25f, 1.234567f, 6.5f};
static uint8_t wire[kMaxWire];

int main() {
    UBRR0 = 16;
    UCSR0A = 1 << U2X0;
    UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);
    UCSR0B = 1 << TXEN0;
    fdev_setup_stream(&uart_out, uart_putc, NULL, _FDEV_SETUP_WRITE);
    stdout = &uart_out;
    const uint16_t oh = overhead();

    Telemetry t;
    memset(&t, 0, sizeof t);
    t_start();
    t.set_omega_r(g_in[0]);
    t.set_omega_l(g_in[1]);
    t.set_tau_cmd_r(g_in[2]);
    t.set_tau_cmd_l(g_in[3]);
    t.set_pwm_r(g_in[4]);
    t.set_pwm_l(g_in[5]);
    t.set_x_odo(g_in[6]);
    t.set_phi_odo(g_in[7]);
    uint16_t c_set = t_stop() - oh;

    t.t_us = 123456789UL;
    t.enc_r = 100000;
    t.enc_l = -5;
    t.stack_hwm = 812;
    t_start();
    uint16_t n = encode_message(t, 4242, wire, sizeof wire);
    uint16_t c_enc = t_stop() - oh;

    Decoder d;
    uint16_t c_dec_max = 0;
    uint32_t c_dec_sum = 0;
    uint8_t ok = 0;
    for (uint16_t i = 0; i < n; ++i) {
        t_start();
        Decoder::Status s = d.feed(wire[i]);
        uint16_t c = t_stop() - oh;
        c_dec_sum += c;
        if (c > c_dec_max) c_dec_max = c;
        if (s == Decoder::kFrame) ok = 1;
    }
    static Telemetry u;  // static: the decode must really be stored
    t_start();
    bool dec_ok = u.decode(d.frame().payload, d.frame().len);
    uint16_t c_unpack = t_stop() - oh;

    uint8_t buf[64];
    for (uint8_t i = 0; i < sizeof buf; ++i) buf[i] = i * 7u;
    t_start();
    volatile uint16_t crc = crc16(buf, sizeof buf);
    uint16_t c_crc = t_stop() - oh;
    (void)crc;

    printf("lib/protocol on ATmega2560 @16 MHz (avr-gcc -Os), cycles:\n");
    printf("  8 saturating float setters           %u (%u per field)\n", c_set, c_set / 8);
    printf("  encode_message(Telemetry) %u B wire  %u (%u us)\n", n, c_enc, c_enc / 16);
    printf("  crc16 over 64 B                      %u (%u per byte)\n", c_crc, c_crc / 64);
    printf("  Decoder::feed, %u bytes              total %lu, max per byte %u (the delimiter: COBS+CRC)\n",
           n, (unsigned long)c_dec_sum, c_dec_max);
    printf("  Telemetry::decode                    %u (enc_r %ld)\n", c_unpack, (long)u.enc_r);
    printf("  frame verified: %s, fields decoded: %s\n", ok ? "yes" : "NO", dec_ok ? "yes" : "NO");
    while (!(UCSR0A & (1 << UDRE0))) {
    }
    for (volatile uint16_t i = 0; i < 2000; ++i) {
    }
    cli();
    sleep_cpu();
    return 0;
}
