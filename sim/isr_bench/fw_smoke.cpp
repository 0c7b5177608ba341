/*
 * System check of the real firmware.elf in simavr (libsimavr): XBee link on USART2 through
 * lib/protocol's codec (host build), encoder stimulus on PD0..PD3, per-ISR cycle accounting.
 * Not the firmware-in-the-loop simulator (sim/fil): the wheels turn at a fixed stimulus speed,
 * there is no plant. It reports what the firmware measures about itself (task cycles, stack
 * high-water mark) and checks commands, Acks, the host-timeout failsafe and the watchdog.
 * Cycle accounting and interrupt-timing corrections: sim/common. Exit status 0 when every
 * check passed.
 * Usage: fw_smoke FIRMWARE.elf
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include <cxxabi.h>

#include <algorithm>
#include <string>
#include <vector>

extern "C" {
#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
}

#include <protocol/frame.h>
#include <protocol/messages.h>

#include "avrsim.h"
#include "board_sim.h"

namespace {
const double kF = AVRSIM_F_CPU_HZ;
avrsim_t sim;
avr_t* avr;
avr_irq_t* uart_in;
avr_irq_t* pin_irq[2][2];  // [wheel: 0 left, 1 right][channel: 0 A, 1 B]
const int kEncBit[2][2] = {{ENC_LEFT_A_BIT, ENC_LEFT_B_BIT}, {ENC_RIGHT_A_BIT, ENC_RIGHT_B_BIT}};
proto::Decoder dec;
uint16_t host_seq = 100;
unsigned long tx_bytes;
int failures;

std::vector<proto::Telemetry> telem;
std::vector<double> telem_t;
std::vector<proto::Ack> acks;
int params_frames;

void on_uart_out(avr_irq_t*, uint32_t value, void*) {
    ++tx_bytes;
    proto::Decoder::Status s = dec.feed(static_cast<uint8_t>(value));
    if (s != proto::Decoder::kFrame) return;
    const proto::Frame& f = dec.frame();
    if (f.type == proto::kMsgTelemetry) {
        proto::Telemetry t;
        if (t.decode(f.payload, f.len)) { telem.push_back(t); telem_t.push_back(avr->cycle / kF); }
    } else if (f.type == proto::kMsgAck) {
        proto::Ack a;
        if (a.decode(f.payload, f.len)) acks.push_back(a);
    } else if (f.type == proto::kMsgParams) {
        ++params_frames;
    }
}

double brake_seen_t = -1;  // first time both brake pins were seen high while watching
bool watch_brake;

std::vector<unsigned long long> pc_cycles;
uint32_t kick_pc;                       // address of wdt_kick(): main-loop iterations
avr_cycle_count_t last_kick, max_kick_gap;  // --profile: cycles spent per flash address

void step() {
    avrsim_step(&sim);
    if (!pc_cycles.empty() && avr->state == cpu_Running) pc_cycles[sim.pc_before] += avr->cycle - sim.cycle_before;
    if (kick_pc && avr->pc == kick_pc) {
        if (last_kick && avr->cycle - last_kick > max_kick_gap) max_kick_gap = avr->cycle - last_kick;
        last_kick = avr->cycle;
    }
    if (watch_brake && brake_seen_t < 0 && (avr->data[MOTOR_BRAKE_PORT] & MOTOR_BRAKE_MASK) == MOTOR_BRAKE_MASK)
        brake_seen_t = avr->cycle / kF;
}

// encoder stimulus: both wheels forward at `edges_per_s` each (0 = stopped)
double enc_rate = 0, next_edge_l = 0, next_edge_r = 0;
int pos_l, pos_r;
const uint8_t gray[4] = {0, 1, 3, 2};
void drive(int wheel, int pos) {
    uint8_t s = gray[pos & 3];  // (B,A)
    avr_raise_irq(pin_irq[wheel][0], s & 1);
    avr_raise_irq(pin_irq[wheel][1], (s >> 1) & 1);
}

void run_for(double seconds) {
    avr_cycle_count_t end = avr->cycle + static_cast<avr_cycle_count_t>(seconds * kF);
    avrsim_stop_at(&sim, end);
    while (avr->cycle < end) {
        if (enc_rate > 0) {
            double c = static_cast<double>(avr->cycle);
            // forward: left wheel is wired B-before-A (ENC_LEFT_REVERSED), right A-before-B
            if (c >= next_edge_l) { --pos_l; drive(0, pos_l); next_edge_l += kF / enc_rate; }
            if (c >= next_edge_r) { ++pos_r; drive(1, pos_r); next_edge_r += kF / enc_rate; }
            if (sim.asleep)  // wake the simulation (not the core) at the next edge
                avrsim_stop_at(&sim, std::min(end, static_cast<avr_cycle_count_t>(std::min(next_edge_l, next_edge_r)) + 1));
        }
        step();
    }
}

double last_send_end;  // when the last byte sent to the robot has been received (s)
void send_bytes(const uint8_t* p, uint16_t n) {
    for (uint16_t i = 0; i < n; ++i) avr_raise_irq(uart_in, p[i]);
    last_send_end = avr->cycle / kF + n * 10.0 / proto::kBaud;
}
template <class M>
void send(const M& m) {
    uint8_t buf[proto::kMaxWire];
    uint16_t n = proto::encode_message(m, host_seq++, buf, sizeof buf);
    send_bytes(buf, n);
}

void check(bool ok, const char* what) {
    printf("%s  %s\n", ok ? "PASS" : "FAIL", what);
    if (!ok) ++failures;
}

bool last_ack_is(uint8_t type, uint8_t result) {
    if (acks.empty()) return false;
    const proto::Ack& a = acks.back();
    return a.cmd_type == type && a.result == result;
}

void print_timing(const proto::Telemetry& t) {
    printf("  task cycles last/max/overruns: inner %u/%u/%u  outer %u/%u/%u  telemetry %u/%u/%u\n",
           t.inner_last * 16, t.inner_max * 16, t.inner_overruns, t.outer_last * 16, t.outer_max * 16,
           t.outer_overruns, t.telemetry_last * 16, t.telemetry_max * 16, t.telemetry_overruns);
    printf("  stack high-water %u bytes, reset_cause 0x%02x, failsafe %u, status 0x%02x\n", t.stack_hwm,
           t.reset_cause, t.failsafe, t.status);
}
}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) { fprintf(stderr, "usage: %s firmware.elf\n", argv[0]); return 2; }
    char err[256];
    if (avrsim_open(&sim, argv[1], err, sizeof err)) { fprintf(stderr, "fw_smoke: %s\n", err); return 2; }
    avr = sim.avr;
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS(SIM_XBEE_UART_DIGIT), &flags);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(SIM_XBEE_UART_DIGIT), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(SIM_XBEE_UART_DIGIT), UART_IRQ_OUTPUT), on_uart_out, NULL);
    for (int w = 0; w < 2; ++w)
        for (int ch = 0; ch < 2; ++ch) {
            pin_irq[w][ch] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(SIM_ENC_PORT_LETTER), kEncBit[w][ch]);
            avr_raise_irq(pin_irq[w][ch], 0);
        }
    long a_hang_l = avrsim_data_symbol(argv[1], "g_fault_hang");
    uint32_t a_hang = a_hang_l < 0 ? 0 : static_cast<uint32_t>(a_hang_l);
    long kick = avrsim_symbol(argv[1], "_Z8wdt_kickv");
    kick_pc = kick < 0 ? 0 : static_cast<uint32_t>(kick);
    bool profile = argc > 2 && strcmp(argv[2], "--profile") == 0;
    if (profile) pc_cycles.assign(256 * 1024, 0);

    // 1. boot, idle
    run_for(1.0);
    check(params_frames == 1, "Params frame sent once after reset");
    check(telem.size() >= 48 && telem.size() <= 51, "about 50 telemetry frames per second while idle");
    bool seq_ok = telem.size() > 1;
    double max_jit = 0;
    for (size_t i = 1; i < telem.size(); ++i) {
        double dt = (telem[i].t_us - telem[i - 1].t_us) * 1e-6;
        if (dt < 0.0195 || dt > 0.0205) seq_ok = false;
        if (fabs(dt - 0.02) > max_jit) max_jit = fabs(dt - 0.02);
    }
    printf("  telemetry period jitter: max |dt - 20 ms| = %.1f us\n", max_jit * 1e6);
    check(seq_ok, "telemetry board time advances 20 ms per frame");
    if (!seq_ok) for (size_t i = 1; i < telem.size() && i < 8; ++i) printf("    dt %u us\n", (unsigned)(telem[i].t_us - telem[i-1].t_us));
    check(!telem.empty() && (telem.back().status & proto::kStatusMotorsEnabled) == 0, "motors off after reset");
    if (!telem.empty()) {
        const proto::Telemetry& t = telem.back();
        check(t.inner_overruns == 0 && t.outer_overruns == 0 && t.telemetry_overruns == 0 &&
                  t.telemetry_max * 16ul <= proto::kTelemetryBudgetCycles,
              "no task overran its budget in the first second after boot");
        print_timing(t);
    }
    printf("  telemetry bytes/s on the wire: %.0f (%.1f%% of %lu baud at 10 bits/byte)\n",
           tx_bytes / 1.0, 100.0 * tx_bytes * 10.0 / proto::kBaud, (unsigned long)proto::kBaud);

    // 2. commands and rejections
    send(proto::RequestParams());
    run_for(0.05);
    check(params_frames == 2, "RequestParams answered with Params");
    {   // bad CRC: flip a payload byte of a valid frame (COBS stays valid)
        proto::SetClamp c; c.on = 1;
        uint8_t buf[proto::kMaxWire];
        uint16_t n = proto::encode_message(c, host_seq++, buf, sizeof buf);
        // wire: 00 code ver type seq seq on crc crc 00 -- corrupt `on` (1 -> 0x41), COBS intact
        buf[6] ^= 0x40;
        send_bytes(buf, n);
        run_for(0.05);
        check(last_ack_is(proto::kMsgSetClamp, proto::kResultBadCrc), "corrupted frame -> Ack bad_crc");
    }
    {
        uint8_t pl[1] = {0};
        uint8_t buf[proto::kMaxWire];
        uint16_t n = proto::encode_frame(0x55, host_seq++, pl, 1, buf, sizeof buf);
        send_bytes(buf, n);
        run_for(0.05);
        check(last_ack_is(0x55, proto::kResultUnknownType), "unknown type -> Ack unknown_type");
    }
    {
        proto::SetMu m; m.mu_s = 2000; m.mu_k = 3000;  // mu_k > mu_s
        send(m);
        run_for(0.05);
        check(last_ack_is(proto::kMsgSetMu, proto::kResultOutOfRange), "SetMu mu_k > mu_s -> out_of_range");
        check(!telem.empty() && (telem.back().status & proto::kStatusParamsDefault), "...and nothing changed");
    }
    {
        proto::Start s; s.profile = 1; s.wheel_accel = 4800; s.accel_time = 500; s.duration = 2000; s.radius = 10;
        send(s);
        run_for(0.05);
        check(last_ack_is(proto::kMsgStart, proto::kResultOutOfRange) && acks.back().detail == 4,
              "arc with radius 0.01 m -> out_of_range, detail = radius field");
        check((telem.back().status & proto::kStatusRunning) == 0, "...and no experiment started");
    }

    {   // valid settings while idle: acknowledged and applied (rebuilds the controller config)
        max_kick_gap = 0;
        proto::SetMu m; m.mu_s = 2410; m.mu_k = 2390;
        send(m);
        run_for(0.05);
        check(last_ack_is(proto::kMsgSetMu, proto::kResultOk), "SetMu while idle -> ok");
        check((telem.back().status & proto::kStatusParamsDefault) == 0, "...and the parameters changed");
        proto::SetClamp c; c.on = 1;
        send(c);
        run_for(0.05);
        check(last_ack_is(proto::kMsgSetClamp, proto::kResultOk), "SetClamp while idle -> ok");
        printf("  longest main-loop iteration around SetMu/SetClamp (controller rebuild): %.2f ms\n",
               max_kick_gap / kF * 1e3);
    }

    // 3. experiment: straight line 48 rad/s^2, wheels turning at 10 rad/s (stimulus)
    enc_rate = 10.0 * ENC_COUNTS_PER_REV / 6.283185307;
    next_edge_l = next_edge_r = static_cast<double>(avr->cycle);
    run_for(0.3);  // the wheels already turn before the Start (0.11 m of idle odometry)
    send(proto::Heartbeat());
    run_for(0.01);
    {
        proto::Start s; s.profile = 0; s.wheel_accel = 4800; s.accel_time = 500; s.duration = 3000; s.radius = 0;
        send(s);
        max_kick_gap = 0;
        size_t n0 = telem.size();
        for (int i = 0; i < 10; ++i) { run_for(0.1); send(proto::Heartbeat()); }
        check(last_ack_is(proto::kMsgHeartbeat, proto::kResultOk), "heartbeats acknowledged");
        bool ran = false, moved = false;
        for (size_t i = n0; i < telem.size(); ++i) {
            if (telem[i].status & proto::kStatusRunning) ran = true;
            if (telem[i].pwm_r != 0 && telem[i].tau_cmd_r != 0) moved = true;
        }
        check(ran && moved, "Start runs the control loops (torque and PWM reported)");
        const proto::Telemetry& t = telem.back();
        printf("  during run: enc_r %ld enc_l %ld omega_r %.2f omega_l %.2f tau_r %.4f pwm_r %.4f x %.3f\n",
               (long)t.enc_r, (long)t.enc_l, t.omega_r * 0.01, t.omega_l * 0.01, t.tau_cmd_r * 1e-4,
               t.pwm_r * 1e-4, t.x_odo * 1e-6);
        check(t.enc_r > 0 && t.enc_l > 0 && t.omega_r > 900 && t.omega_r < 1100 && t.omega_l > 900,
              "encoders count forward and omega ~ 10 rad/s on both wheels");
        check(t.illegal_r == 0 && t.illegal_l == 0, "no illegal transitions");
        {
            proto::SetMu m; m.mu_s = 3000; m.mu_k = 2000;
            send(m);
            run_for(0.03);
            check(last_ack_is(proto::kMsgSetMu, proto::kResultBusy), "SetMu while running -> busy");
            send(proto::Heartbeat());
            run_for(0.01);
        }
        print_timing(t);
        printf("  longest main-loop iteration during the run: %.2f ms (watchdog 250 ms)\n", max_kick_gap / kF * 1e3);
        // 4. host goes silent: brake within 500 ms
        double silent_at = last_send_end;  // the last host frame has been received
        watch_brake = true;
        size_t n1 = telem.size();
        run_for(0.7);
        double brake_t = -1;
        for (size_t i = n1; i < telem.size(); ++i)
            if (telem[i].failsafe == proto::kFailsafeHostTimeout) { brake_t = telem_t[i]; break; }
        check(brake_t > 0, "host silent -> failsafe host_timeout reported");
        {   // odometry continues from the run's pose after the stop (the wheels still turn)
            const proto::Telemetry& a = telem[n1 > 0 ? n1 - 1 : 0];
            const proto::Telemetry& b = telem.back();
            // 0.7 s at 10 rad/s * r = 0.256 m more; a restart from the idle odometry
            // of before the Start would add its 0.11 m too
            long dx = static_cast<long>(b.x_odo) - static_cast<long>(a.x_odo);
            printf("  x before the silence %.3f m, 0.7 s later %.3f m\n", a.x_odo * 1e-6, b.x_odo * 1e-6);
            check(dx > 200000 && dx < 300000, "after the stop, odometry continues from the run's last pose");
            bool mono = true;  // no frame (the first after the stop included) jumps back
            for (size_t i = n1; i < telem.size(); ++i)
                if (telem[i].x_odo < telem[i - 1].x_odo) {
                    mono = false;
                    printf("  x_odo went back: frame %zu %.4f m -> %.4f m (status 0x%02x)\n", i,
                           telem[i - 1].x_odo * 1e-6, telem[i].x_odo * 1e-6, telem[i].status);
                }
            check(mono, "x_odo never goes back across the stop (wheels turning forward)");
        }
        check((avr->data[MOTOR_BRAKE_PORT] & MOTOR_BRAKE_MASK) == MOTOR_BRAKE_MASK, "brake pins D8/D9 high");
        check(brake_seen_t > 0 && brake_seen_t - silent_at <= 0.500 && brake_seen_t - silent_at >= 0.498,
              "brake applied within 500 ms of the last host frame, and not before 498 ms");
        if (brake_t > 0)
            printf("  brake pins high %.2f ms after the last host byte; failsafe in telemetry at %.1f ms\n",
                   (brake_seen_t - silent_at) * 1000, (brake_t - silent_at) * 1000);
        print_timing(telem.back());
    }
    {   // 4b. a short experiment that ends by itself (duration reached)
        proto::Start s; s.profile = 0; s.wheel_accel = 4800; s.accel_time = 100; s.duration = 300; s.radius = 0;
        send(s);
        run_for(0.03);
        size_t n3 = telem.size();
        for (int i = 0; i < 6; ++i) { run_for(0.1); send(proto::Heartbeat()); }
        bool finished = false, mono = true, moved = false;
        for (size_t i = n3 + 1; i < telem.size(); ++i) {
            if (telem[i].failsafe == proto::kFailsafeFinished) finished = true;
            if (telem[i].x_odo < telem[i - 1].x_odo) mono = false;
            if (telem[i].x_odo > 50000) moved = true;
        }
        check(finished && (telem.back().status & proto::kStatusRunning) == 0,
              "experiment ends at its duration: failsafe finished, not running");
        check(mono && moved, "x_odo continues across the end of the experiment (no reset to 0)");
    }
    enc_rate = 0;

    // 5. watchdog: hang the main loop
    if (a_hang) {
        avr->data[a_hang] = 1;
        size_t n2 = telem.size();
        run_for(0.6);
        bool wd = false;
        for (size_t i = n2; i < telem.size(); ++i)
            if ((telem[i].reset_cause & proto::kResetCauseWatchdog) && telem[i].failsafe == proto::kFailsafeWatchdogReset) wd = true;
        check(wd, "main-loop hang -> watchdog reset, reset_cause WDRF and failsafe watchdog_reset reported");
        check(!telem.empty() && (telem.back().status & proto::kStatusMotorsEnabled) == 0, "motors off after the watchdog reset");
    }

    printf("\n# ISR cycles per invocation (sim/common corrections: response %u, +%u from sleep), whole run\n"
           "%-8s %10s %6s %8s\n", AVRSIM_IRQ_RESPONSE_CYCLES, AVRSIM_WAKE_CYCLES, "vector", "calls", "max", "mean");
    for (int v = 0; v < AVRSIM_VECTORS; ++v)
        if (sim.isr[v].calls)
            printf("%-8d %10lu %6lu %8.1f\n", v, sim.isr[v].calls, sim.isr[v].max_cycles, sim.isr[v].sum_cycles / sim.isr[v].calls);
    if (profile) {  // cycles per function over the whole run (ELF symbol sizes)
        struct F { unsigned long long c; std::string name; };
        struct Ctx { std::vector<F> fs; } ctx;
        avrsim_each_symbol(argv[1], [](unsigned long a, unsigned long n, int is_func, const char* name, void* p) {
            if (!is_func) return;
            unsigned long long c = 0;
            for (unsigned long i = a; i < a + n && i < pc_cycles.size(); ++i) c += pc_cycles[i];
            if (!c) return;
            int st = 0;
            char* dm = abi::__cxa_demangle(name, nullptr, nullptr, &st);
            static_cast<Ctx*>(p)->fs.push_back(F{c, st == 0 && dm ? dm : name});
            free(dm);
        }, &ctx);
        std::sort(ctx.fs.begin(), ctx.fs.end(), [](const F& x, const F& y) { return x.c > y.c; });
        printf("\n# profile: cycles per function, whole run (top 25)\n");
        for (size_t i = 0; i < ctx.fs.size() && i < 25; ++i) printf("%12llu  %s\n", ctx.fs[i].c, ctx.fs[i].name.c_str());
    }
    printf("\n%s (%d failures)\n", failures ? "FAILED" : "ALL PASSED", failures);
    return failures ? 1 : 0;
}
