/*
 * Firmware in the loop (issue 6): the real megaatmega2560 firmware.elf runs in libsimavr at
 * 16 MHz against lib/slipmodel's slip::Plant, in lockstep with simulated time.
 *
 *   plant      every --plant-dt (default 0.5 ms = 8000 cycles) a cycle timer reads the motor
 *              outputs (OCR3C/OCR1A, COM bits, DIR and BRAKE pins), converts them to signed duty
 *              and calls Plant::step_duty over the next interval.
 *   encoders   the wheel angle is interpolated linearly within each plant step; every crossing
 *              of a count boundary becomes one quadrature edge on PD0..PD3, scheduled as a
 *              simavr cycle timer at the cycle of the crossing (so edges wake a sleeping core
 *              at the right cycle, not once per step).
 *   XBee       USART2 <-> a pseudo-terminal (its path is printed: "PTY /dev/pts/N"); the host
 *              sees the same bytes as from the radio. Host bytes are delivered at the line
 *              rate (10 bits per byte at the USART's actual baud rate).
 *   recording  groundtruth.csv (camera model), plant.csv (true plant state) and fil.json
 *              (measurements, link statistics) in --run-dir, all on the board clock (Timer5,
 *              which the firmware's time_us() counts, started at its first boot).
 * Interrupt timing: the same two corrections as sim/isr_bench (5-cycle interrupt response that
 * simavr does not charge; one main instruction after RETI before the next interrupt).
 * Usage: fil FIRMWARE.elf --run-dir DIR [options]   (fil --help)
 */
#include <elf.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <deque>
#include <random>
#include <string>
#include <vector>

extern "C" {
#include <simavr/avr_extint.h>
#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_cycle_timers.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_interrupts.h>
}

#include <protocol/frame.h>
#include <protocol/messages.h>
#include <slipmodel/effects.h>
#include <slipmodel/keys.h>
#include <slipmodel/plant.h>

#include "board.h"  // firmware wiring: encoder directions, DIR levels, UBRR (plain #defines)

namespace {

const double kF = 16000000.0;
const unsigned kVecEnd = 0xE4;  // 57 vectors x 4 bytes
const double kTwoPi = 6.283185307179586;

// ATmega2560 data-space addresses (avr-libc iom2560.h; I/O registers + 0x20)
const uint16_t kPORTB = 0x25, kPORTE = 0x2E, kPORTH = 0x102;
const uint16_t kTCCR1A = 0x80, kICR1 = 0x86, kOCR1A = 0x88;
const uint16_t kTCCR3A = 0x90, kICR3 = 0x96, kOCR3C = 0x9C;
const uint16_t kTCCR5B = 0x121;
const uint16_t kPIND = 0x29, kPORTD = 0x2B;

[[noreturn]] void die(const char* fmt, const char* a = "", const char* b = "") {
    fprintf(stderr, "fil: error: ");
    fprintf(stderr, fmt, a, b);
    fprintf(stderr, "\n");
    exit(2);
}

// ------------------------------------------------------------------------------- options
struct Options {
    std::string elf, run_dir, pty_link;
    double t_end = 10.0;           // simulated seconds (board time) at most
    double plant_dt = 0.0005;
    double realtime = 1.0;         // pace: simulated s per wall s at most (0 = free running)
    bool wait_host = true;         // after boot, hold the simulation until the host sends a byte
    double boot_s = 0.05;
    double host_wait_s = 30.0;
    bool exit_on_hangup = true;
    std::vector<std::pair<std::string, double>> keys;
    double cam_rate = 100.0, cam_xy = 0.0, cam_phi = 0.0, cam_dropout = 0.0;
    double enc_jitter_us = 0.0, enc_glitch = 0.0;
    double link_ber = 0.0, link_drop = 0.0;
    bool link_up = true, link_down = true;
    double host_silent_at = -1.0;  // board time after which host bytes are discarded
    double hang_at = -1.0;         // board time at which g_fault_hang is set
    double silent_after_run = -1.0, hang_after_run = -1.0;  // ... relative to the experiment start
    unsigned seed = 1;
    int plant_log_every = 1;
    bool pwm_ideal = false;        // duty = OCR / (TOP + 1) instead of the hardware's (OCR + 1) / (TOP + 1)
};
Options opt;

void usage() {
    printf(
        "usage: fil FIRMWARE.elf --run-dir DIR [options]\n"
        "  --t-end S            stop at this board time (default 10)\n"
        "  --plant-dt S         plant step (default 0.0005; a whole number of cycles)\n"
        "  --realtime X         at most X simulated s per wall s; 0 = as fast as possible (default 1)\n"
        "  --no-wait-host       do not hold the simulation after boot until the host sends a byte\n"
        "  --host-wait S        give up when no host byte came within S wall seconds (default 30)\n"
        "  --no-exit-on-hangup  keep running when the host closes the pty\n"
        "  --pty-link PATH      also make a symlink PATH -> the pty\n"
        "  --set KEY=VALUE      plant key (lib/slipmodel keys.h): robot.mu_s=0.3,\n"
        "                       motor_back_emf.enabled=1, motor_back_emf.ke_ratio=1.2, ...\n"
        "  --cam-rate HZ        ground-truth sample rate (default 100)\n"
        "  --cam-noise-xy M     ground-truth position noise, standard deviation (default 0)\n"
        "  --cam-noise-phi RAD  ground-truth heading noise (default 0)\n"
        "  --cam-dropout P      probability that a ground-truth sample is missing (default 0)\n"
        "  --enc-jitter-us US   encoder edge time noise, standard deviation (default 0)\n"
        "  --enc-glitch P       probability per edge of an extra bounce (forth and back, 2 us)\n"
        "  --link-ber P         probability per byte of one flipped bit (default 0)\n"
        "  --link-drop P        probability per byte of losing it (default 0)\n"
        "  --link-dir up|down|both  where corruption applies (default both; up = robot->host)\n"
        "  --host-silent-at S   from this board time on, host bytes no longer reach the robot\n"
        "  --hang-at S          at this board time set the firmware's g_fault_hang (watchdog test)\n"
        "  --host-silent-after-start S, --hang-after-start S\n"
        "                       the same, S seconds after the first telemetry frame that reports\n"
        "                       an experiment running\n"
        "  --seed N             random seed (default 1)\n"
        "  --plant-log-every N  plant.csv row every N plant steps (default 1)\n"
        "  --pwm-model hardware|ideal  fast PWM duty (OCR+1)/(TOP+1) as the ATmega2560 makes it\n"
        "                       (default), or OCR/(TOP+1) as the firmware's torque->PWM map assumes\n");
}

double num(const char* s, const char* what) {
    char* end = nullptr;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end || !isfinite(v)) die("%s: not a number: '%s'", what, s);
    return v;
}

void parse(int argc, char** argv) {
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto val = [&](void) -> const char* {
            if (i + 1 >= argc) die("%s needs a value", a.c_str());
            return argv[++i];
        };
        auto prob = [&](const char* s) {
            double p = num(s, a.c_str());
            if (p < 0 || p > 1) die("%s: %s is not a probability in [0, 1]", a.c_str(), s);
            return p;
        };
        auto nonneg = [&](const char* s) {
            double p = num(s, a.c_str());
            if (p < 0) die("%s: %s must be >= 0", a.c_str(), s);
            return p;
        };
        if (a == "-h" || a == "--help") { usage(); exit(0); }
        else if (a == "--run-dir") opt.run_dir = val();
        else if (a == "--pty-link") opt.pty_link = val();
        else if (a == "--t-end") opt.t_end = nonneg(val());
        else if (a == "--plant-dt") opt.plant_dt = num(val(), "--plant-dt");
        else if (a == "--realtime") opt.realtime = nonneg(val());
        else if (a == "--no-wait-host") opt.wait_host = false;
        else if (a == "--host-wait") opt.host_wait_s = nonneg(val());
        else if (a == "--no-exit-on-hangup") opt.exit_on_hangup = false;
        else if (a == "--set") {
            std::string kv = val();
            size_t eq = kv.find('=');
            if (eq == std::string::npos || eq == 0) die("--set wants KEY=VALUE, got '%s'", kv.c_str());
            opt.keys.push_back({kv.substr(0, eq), num(kv.c_str() + eq + 1, kv.c_str())});
        }
        else if (a == "--cam-rate") { opt.cam_rate = num(val(), "--cam-rate"); if (opt.cam_rate <= 0) die("--cam-rate must be > 0"); }
        else if (a == "--cam-noise-xy") opt.cam_xy = nonneg(val());
        else if (a == "--cam-noise-phi") opt.cam_phi = nonneg(val());
        else if (a == "--cam-dropout") opt.cam_dropout = prob(val());
        else if (a == "--enc-jitter-us") opt.enc_jitter_us = nonneg(val());
        else if (a == "--enc-glitch") opt.enc_glitch = prob(val());
        else if (a == "--link-ber") opt.link_ber = prob(val());
        else if (a == "--link-drop") opt.link_drop = prob(val());
        else if (a == "--link-dir") {
            std::string d = val();
            if (d == "up") { opt.link_up = true; opt.link_down = false; }
            else if (d == "down") { opt.link_up = false; opt.link_down = true; }
            else if (d == "both") { opt.link_up = opt.link_down = true; }
            else die("--link-dir: '%s' is not up, down or both", d.c_str());
        }
        else if (a == "--host-silent-at") opt.host_silent_at = nonneg(val());
        else if (a == "--hang-at") opt.hang_at = nonneg(val());
        else if (a == "--host-silent-after-start") opt.silent_after_run = nonneg(val());
        else if (a == "--hang-after-start") opt.hang_after_run = nonneg(val());
        else if (a == "--pwm-model") {
            std::string m = val();
            if (m == "hardware") opt.pwm_ideal = false;
            else if (m == "ideal") opt.pwm_ideal = true;
            else die("--pwm-model: '%s' is not hardware or ideal", m.c_str());
        }
        else if (a == "--seed") opt.seed = static_cast<unsigned>(nonneg(val()));
        else if (a == "--plant-log-every") { opt.plant_log_every = static_cast<int>(num(val(), a.c_str())); if (opt.plant_log_every < 1) die("--plant-log-every must be >= 1"); }
        else if (a.size() > 1 && a[0] == '-') die("unknown option %s (see --help)", a.c_str());
        else if (opt.elf.empty()) opt.elf = a;
        else die("unexpected argument '%s'", a.c_str());
    }
    if (opt.elf.empty()) die("no firmware ELF given (see --help)");
    if (opt.run_dir.empty()) die("--run-dir is required");
    double c = opt.plant_dt * kF;
    if (!(c >= 100 && c <= 1.6e6) || fabs(c - round(c)) > 1e-6)
        die("--plant-dt must be a whole number of 16 MHz cycles between 100 and 1.6e6");
}

// ------------------------------------------------------------------- ELF symbol lookup
// Value of a symbol in the firmware's ELF symbol table (flash: byte address; data: 0x80xxxx).
long elf_symbol(const char* path, const char* name) {
    FILE* f = fopen(path, "rb");
    if (!f) die("cannot open %s: %s", path, strerror(errno));
    std::vector<unsigned char> d;
    unsigned char buf[65536];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, f)) > 0) d.insert(d.end(), buf, buf + n);
    fclose(f);
    if (d.size() < sizeof(Elf32_Ehdr) || memcmp(d.data(), ELFMAG, SELFMAG) || d[EI_CLASS] != ELFCLASS32)
        die("%s is not a 32-bit ELF file", path);
    Elf32_Ehdr eh;
    memcpy(&eh, d.data(), sizeof eh);
    for (int i = 0; i < eh.e_shnum; ++i) {
        Elf32_Shdr sh;
        size_t off = eh.e_shoff + static_cast<size_t>(i) * eh.e_shentsize;
        if (off + sizeof sh > d.size()) break;
        memcpy(&sh, d.data() + off, sizeof sh);
        if (sh.sh_type != SHT_SYMTAB) continue;
        Elf32_Shdr st;
        memcpy(&st, d.data() + eh.e_shoff + static_cast<size_t>(sh.sh_link) * eh.e_shentsize, sizeof st);
        for (size_t k = 0; k + sizeof(Elf32_Sym) <= sh.sh_size; k += sizeof(Elf32_Sym)) {
            Elf32_Sym s;
            memcpy(&s, d.data() + sh.sh_offset + k, sizeof s);
            if (st.sh_offset + s.st_name >= d.size()) continue;
            const char* nm = reinterpret_cast<const char*>(d.data() + st.sh_offset + s.st_name);
            if (strcmp(nm, name) == 0) return static_cast<long>(s.st_value);
        }
    }
    return -1;
}

// ------------------------------------------------------------------------------ state
avr_t* avr;
avr_irq_t* uart_in;
avr_irq_t* pin_irq[4];  // PD0..PD3: left A, left B, right A, right B
std::mt19937_64 rng;
std::uniform_real_distribution<double> uni(0.0, 1.0);
std::normal_distribution<double> gauss(0.0, 1.0);
avr_cycle_count_t plant_cycles;
avr_cycle_count_t next_plant_at;  // cycle of the next plant step (timer re-armed after a reset)
volatile sig_atomic_t stop_now;
std::string stop_reason = "t_end reached";

// board clock: Timer5 start of the first boot
bool board_running;
bool board_origin_set;
avr_cycle_count_t board_origin;
std::vector<double> boot_at_s, reset_at_s;  // board times of timer starts / resets
double board_t(avr_cycle_count_t c) {
    return (static_cast<double>(c) - static_cast<double>(board_origin)) / kF;
}
double board_now() { return board_t(avr->cycle); }

slip::Plant plant;

// the current plant step, for the wheel angle at any cycle inside it
avr_cycle_count_t step_c0;
double step_s0[2], step_s1[2];  // counts (angle * CPR / 2 pi) at its start and end
double counts_at(int w, avr_cycle_count_t c) {
    double f = (static_cast<double>(c) - static_cast<double>(step_c0)) / static_cast<double>(plant_cycles);
    if (f < 0) f = 0;
    if (f > 1) f = 1;
    return step_s0[w] + f * (step_s1[w] - step_s0[w]);
}
// enc_snapshot() calls of the firmware (the instants it samples its counters): the true counts
long snap_pc = -1;
struct Snap { double t, s_r, s_l; long pins_r, pins_l; };
std::deque<Snap> snaps;
FILE* snap_f;
unsigned long snap_calls;

// encoders (index 0 = right, 1 = left)
struct Edge { avr_cycle_count_t at; long pos; };
std::deque<Edge> edges[2];
bool edge_armed[2];
long pos_now[2];           // quadrature position currently driven on the pins (counts, + forward)
long edges_total[2];
const int kReversed[2] = {ENC_RIGHT_REVERSED, ENC_LEFT_REVERSED};
const uint8_t kGray[4] = {0, 1, 3, 2};  // (B,A)
double counts_per_rad() { return ENC_COUNTS_PER_REV / kTwoPi; }

// ISR accounting. ISRs can nest (the firmware's USART ISRs re-enable interrupts so that the
// encoder ISRs preempt them): a stack of open invocations; each one's own cycles exclude the
// ISRs nested in it.
struct VecStat { unsigned long n = 0, max = 0; double sum = 0; };
VecStat vstat[64];
struct Open { int vec; avr_cycle_count_t start, nested; };
Open isr_stack[16];
int isr_depth;
unsigned long isr_nested_calls;

// link
int pty_fd = -1;
std::string pty_name;
bool host_seen;
std::deque<uint8_t> down_q;  // host bytes waiting to be shifted into USART2
bool down_armed;
avr_cycle_count_t byte_cycles;
struct LinkStats {
    unsigned long up_bytes = 0, up_flipped = 0, up_dropped = 0, up_unsent = 0;
    unsigned long down_bytes = 0, down_flipped = 0, down_dropped = 0, down_silenced = 0;
    double last_down_byte_t = -1;   // board time the last delivered host byte finished
    double last_down_frame_t = -1;  // ... and the last one that completed a valid frame
} link;
proto::Decoder down_clean;   // host stream before corruption: which frames were corrupted
bool down_frame_dirty;
std::vector<unsigned> down_corrupted_seqs;
unsigned long down_frames_total, down_frames_corrupted;
proto::Decoder down_after;   // what the robot received (complete, valid frames)

// telemetry tap (the robot's bytes before link corruption)
proto::Decoder up_dec;
unsigned long telem_frames, params_frames, ack_frames;
double enc_err_max[2];
unsigned long enc_pin_mismatch;  // frames whose counts differ from the edges driven at the snapshot
double snap_lag_max;
unsigned long enc_checked;
uint32_t task_max[3], task_max_run[3];      // whole run / frames with status "running"
unsigned task_overruns_max[3], task_overruns_run[3];
unsigned long running_frames;
double run_start_t = -1;  // board time of the first frame reporting an experiment running
unsigned illegal_max[2];
uint8_t last_failsafe = 0;
struct FsEvent { double t; unsigned code; unsigned boot; };
std::vector<FsEvent> failsafe_events;
std::vector<std::pair<double, unsigned>> reset_causes;  // first frame of every boot
unsigned telem_boot = 0;
uint16_t last_seq;
bool have_seq;
unsigned long seq_restarts;

// motor outputs
double duty[2];
bool braking = true;
std::vector<double> brake_on_t, brake_off_t;
unsigned long steps_slipping[2];
double max_slip_speed;

// hang injection
long hang_addr = -1;
bool hang_done;
double hang_t = -1;

// recording
FILE* gt_f;
FILE* plant_f;
double next_cam_t;
unsigned long plant_steps;
unsigned long gt_rows, gt_missing;

// pacing
struct timespec wall0;
double wall_now() {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return static_cast<double>(t.tv_sec - wall0.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec - wall0.tv_nsec);
}
double sim_t_at_pace0, wall_at_pace0, wall_waiting;

// ----------------------------------------------------------------------------- helpers
uint16_t rd16(uint16_t a) { return static_cast<uint16_t>(avr->data[a] | (avr->data[a + 1] << 8)); }

// Signed duty of one shield channel from the timer/pin registers: fast PWM (WGM 14, TOP = ICRn)
// non-inverting: the output is high for OCR + 1 of TOP + 1 counts (100 % when OCR >= TOP);
// COM bits off: the pin is a plain output (PORT level). BRAKE high: both L298 inputs equal ->
// no drive voltage (terminals shorted while enable is high): duty 0. The plant's duty model
// gives the averaged voltage u * supply; enable low (coast) is approximated by u = 0 as well.
double channel_duty(int w) {
    bool right = w == 0;
    uint8_t porth = avr->data[kPORTH];
    bool brake = right ? (porth & (1 << 6)) : (porth & (1 << 5));
    if (brake) return 0.0;
    uint8_t tccra = avr->data[right ? kTCCR3A : kTCCR1A];
    bool com = right ? (tccra & (1 << 3)) : (tccra & (1 << 7));  // COM3C1 / COM1A1
    double mag;
    if (com) {
        double top = rd16(right ? kICR3 : kICR1);
        double ocr = rd16(right ? kOCR3C : kOCR1A);
        if (opt.pwm_ideal) mag = ocr >= top + 1 ? 1.0 : ocr / (top + 1.0);
        else mag = ocr >= top ? 1.0 : (ocr + 1.0) / (top + 1.0);
    } else {
        uint8_t port = avr->data[right ? kPORTE : kPORTB];
        mag = (port & (1 << 5)) ? 1.0 : 0.0;  // PE5 / PB5 as a plain output
    }
    uint8_t portb = avr->data[kPORTB];
    int level = right ? ((portb >> 6) & 1) : ((portb >> 7) & 1);
    int fwd_level = right ? MOTOR_RIGHT_DIR_FORWARD_LEVEL : MOTOR_LEFT_DIR_FORWARD_LEVEL;
    return level == fwd_level ? mag : -mag;
}

// The encoder outputs drive PD0..PD3. simavr 1.6 models the firmware's pull-ups (PORTD |= 0x0F
// in enc_init) by raising the input pins to 1, over any level driven from outside. The simulated
// encoders therefore start in the phase where both channels are high ((B,A) = 11, Gray index 2):
// the pull-up write changes nothing and the first edge is counted. After a watchdog reset the
// wheels stand at an arbitrary phase and the same write can move a low line to 1: counted as
// pin_conflicts in fil.json (the encoder check covers the first boot only).
const int kPhase0 = 2;
uint8_t pins_driven = 0x0F;  // PD0..PD3 as driven by the encoders
unsigned long pin_conflicts;

void drive_pins(int w, long pos) {
    long g = kReversed[w] ? -pos : pos;
    uint8_t s_old = kGray[static_cast<unsigned long>((kReversed[w] ? -pos_now[w] : pos_now[w]) + kPhase0) & 3u];
    uint8_t s = kGray[static_cast<unsigned long>(g + kPhase0) & 3u];
    int base = w == 0 ? 2 : 0;  // right on PD2/PD3, left on PD0/PD1
    pins_driven = static_cast<uint8_t>((pins_driven & ~(3u << base)) | (static_cast<unsigned>(s) << base));
    if ((s ^ s_old) & 1) avr_raise_irq(pin_irq[base], s & 1);
    if ((s ^ s_old) & 2) avr_raise_irq(pin_irq[base + 1], (s >> 1) & 1);
    pos_now[w] = pos;
    ++edges_total[w];
}

avr_cycle_count_t edge_cb(avr_t*, avr_cycle_count_t, void* param) {
    int w = static_cast<int>(reinterpret_cast<intptr_t>(param));
    while (!edges[w].empty() && edges[w].front().at <= avr->cycle) {
        drive_pins(w, edges[w].front().pos);
        edges[w].pop_front();
    }
    if (edges[w].empty()) { edge_armed[w] = false; return 0; }
    return edges[w].front().at;
}

void arm_edges(int w) {
    if (edge_armed[w] || edges[w].empty()) return;
    avr_cycle_count_t at = edges[w].front().at;
    avr_cycle_timer_register(avr, at > avr->cycle ? at - avr->cycle : 0, edge_cb,
                             reinterpret_cast<void*>(static_cast<intptr_t>(w)));
    edge_armed[w] = true;
}

// Count-boundary crossings of one wheel in [c0, c0 + n) as the angle goes s0 -> s1 (counts).
void schedule_edges(int w, double s0, double s1, avr_cycle_count_t c0, avr_cycle_count_t n) {
    long p0 = static_cast<long>(floor(s0)), p1 = static_cast<long>(floor(s1));
    if (p0 == p1) return;
    int dir = p1 > p0 ? 1 : -1;
    avr_cycle_count_t last = edges[w].empty() ? c0 : edges[w].back().at;
    double jitter = opt.enc_jitter_us * 16.0;
    for (long k = p0; k != p1; k += dir) {
        double boundary = dir > 0 ? static_cast<double>(k + 1) : static_cast<double>(k);
        double f = (boundary - s0) / (s1 - s0);
        double at = static_cast<double>(c0) + ceil(f * static_cast<double>(n));
        if (jitter > 0) at += jitter * gauss(rng);
        avr_cycle_count_t ac = at < static_cast<double>(last) + 1 ? last + 1 : static_cast<avr_cycle_count_t>(at);
        long np = k + dir;
        edges[w].push_back({ac, np});
        last = ac;
        if (opt.enc_glitch > 0 && uni(rng) < opt.enc_glitch) {  // bounce: one channel forth and back
            edges[w].push_back({last + 32, np + dir});
            edges[w].push_back({last + 64, np});
            last += 64;
        }
    }
}

void write_plant_row(const slip::PlantState& s, double t) {
    if (!plant_f || t < 0) return;
    fprintf(plant_f,
            "%.6f,%.9f,%.9f,%.9f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.5f,%.5f,%.6f,%.6f,%d,%d,%ld,%ld,%.3f,%.3f\n",
            t, s.x_m, s.y_m, s.phi_rad, s.v_m_s, s.w_m_s, s.omega_rad_s, s.theta_r_rad, s.theta_l_rad,
            s.dtheta_r_rad_s, s.dtheta_l_rad_s, duty[0], duty[1], s.tau_r_nm, s.tau_l_nm,
            s.slipping_r ? 1 : 0, s.slipping_l ? 1 : 0, pos_now[0], pos_now[1],
            s.theta_r_rad * counts_per_rad(), s.theta_l_rad * counts_per_rad());
}

// camera samples at board times k / cam_rate inside (t0, t1], interpolated linearly
void camera(double t0, double x0, double y0, double p0, double t1, double x1, double y1, double p1) {
    if (!gt_f || !board_origin_set) return;
    while (next_cam_t <= t1) {
        double t = next_cam_t;
        next_cam_t += 1.0 / opt.cam_rate;
        if (t < t0 || t < 0) continue;
        if (opt.cam_dropout > 0 && uni(rng) < opt.cam_dropout) { ++gt_missing; continue; }
        double f = t1 > t0 ? (t - t0) / (t1 - t0) : 1.0;
        double x = x0 + f * (x1 - x0), y = y0 + f * (y1 - y0), ph = p0 + f * (p1 - p0);
        if (opt.cam_xy > 0) { x += opt.cam_xy * gauss(rng); y += opt.cam_xy * gauss(rng); }
        if (opt.cam_phi > 0) ph += opt.cam_phi * gauss(rng);
        fprintf(gt_f, "%.6f,%.6f,%.6f,%.6f\n", t, x, y, ph);
        ++gt_rows;
    }
}

// ------------------------------------------------------------------------ link (down)
uint8_t corrupt(uint8_t b, bool* flipped, bool* dropped, bool on) {
    *flipped = *dropped = false;
    if (!on) return b;
    if (opt.link_drop > 0 && uni(rng) < opt.link_drop) { *dropped = true; return b; }
    if (opt.link_ber > 0 && uni(rng) < opt.link_ber) {
        *flipped = true;
        return static_cast<uint8_t>(b ^ (1u << static_cast<unsigned>(uni(rng) * 8) % 8));
    }
    return b;
}

avr_cycle_count_t down_cb(avr_t*, avr_cycle_count_t when, void*) {
    if (down_q.empty()) { down_armed = false; return 0; }
    uint8_t b = down_q.front();
    down_q.pop_front();
    avr_raise_irq(uart_in, b);
    ++link.down_bytes;
    link.last_down_byte_t = board_now();
    if (down_after.feed(b) == proto::Decoder::kFrame) link.last_down_frame_t = board_now();
    return when + byte_cycles;
}

void host_byte(uint8_t b) {
    // what the host meant to send: frame bookkeeping for the corruption report
    bool flipped, dropped;
    uint8_t c = corrupt(b, &flipped, &dropped, opt.link_down);
    if (flipped || dropped) down_frame_dirty = true;
    proto::Decoder::Status s = down_clean.feed(b);
    if (b == 0) {  // frame delimiter
        if (s == proto::Decoder::kFrame) {
            ++down_frames_total;
            if (down_frame_dirty) {
                ++down_frames_corrupted;
                if (down_corrupted_seqs.size() < 10000) down_corrupted_seqs.push_back(down_clean.frame().seq);
            }
        }
        down_frame_dirty = false;
    }
    if (dropped) { ++link.down_dropped; return; }
    if (flipped) ++link.down_flipped;
    down_q.push_back(c);
    if (!down_armed) {
        avr_cycle_timer_register(avr, byte_cycles, down_cb, nullptr);
        down_armed = true;
    }
}

// Reads what the host wrote into the pty. Returns false when the host has hung up.
bool poll_host() {
    if (pty_fd < 0) return true;
    uint8_t buf[256];
    for (;;) {
        ssize_t n = read(pty_fd, buf, sizeof buf);
        if (n > 0) {
            host_seen = true;
            bool silent = board_origin_set &&
                          ((opt.host_silent_at >= 0 && board_now() >= opt.host_silent_at) ||
                           (opt.silent_after_run >= 0 && run_start_t >= 0 && board_now() >= run_start_t + opt.silent_after_run));
            for (ssize_t i = 0; i < n; ++i) {
                if (silent) ++link.down_silenced;
                else host_byte(buf[i]);
            }
            continue;
        }
        if (n < 0 && errno == EAGAIN) return true;
        if (n < 0 && errno == EINTR) continue;
        return !host_seen;  // EIO (no slave open) or EOF: a hang-up once the host was there
    }
}

// ------------------------------------------------------------------------- link (up)
void on_uart_out(avr_irq_t*, uint32_t value, void*) {
    uint8_t b = static_cast<uint8_t>(value);
    // tap: decode the robot's own bytes (before the link) for the measurements in fil.json
    if (up_dec.feed(b) == proto::Decoder::kFrame) {
        const proto::Frame& f = up_dec.frame();
        if (have_seq && f.seq != static_cast<uint16_t>(last_seq + 1)) ++seq_restarts;
        have_seq = true;
        last_seq = f.seq;
        if (f.type == proto::kMsgTelemetry) {
            proto::Telemetry t;
            if (t.decode(f.payload, f.len)) {
                ++telem_frames;
                unsigned boot = static_cast<unsigned>(boot_at_s.size());
                double tb = boot_at_s.empty() ? 0 : boot_at_s.back() + t.t_us * 1e-6;
                if (boot != telem_boot || reset_causes.empty()) {
                    reset_causes.push_back({tb, t.reset_cause});
                    telem_boot = boot;
                }
                uint32_t cyc[3] = {t.get_inner_max_cycles(), t.get_outer_max_cycles(), t.get_telemetry_max_cycles()};
                unsigned ovr[3] = {t.inner_overruns, t.outer_overruns, t.telemetry_overruns};
                bool running = t.status & proto::kStatusRunning;
                if (running) ++running_frames;
                if (running && run_start_t < 0) run_start_t = tb;
                for (int i = 0; i < 3; ++i) {
                    if (cyc[i] > task_max[i]) task_max[i] = cyc[i];
                    if (ovr[i] > task_overruns_max[i]) task_overruns_max[i] = ovr[i];
                    if (running && cyc[i] > task_max_run[i]) task_max_run[i] = cyc[i];
                    if (running && ovr[i] > task_overruns_run[i]) task_overruns_run[i] = ovr[i];
                }
                if (t.illegal_r > illegal_max[0]) illegal_max[0] = t.illegal_r;
                if (t.illegal_l > illegal_max[1]) illegal_max[1] = t.illegal_l;
                if (t.failsafe != last_failsafe) {
                    failsafe_events.push_back({tb, t.failsafe, boot});
                    last_failsafe = t.failsafe;
                }
                // encoder check (first boot: the firmware's counts start at the plant's zero):
                // the frame's counts against the true counts at the frame's own enc_snapshot()
                // call (the last one before its time stamp t_us, taken right after it)
                if (boot == 1 && !snaps.empty()) {
                    const Snap* sn = nullptr;
                    for (size_t i = snaps.size(); i-- > 0;)
                        if (snaps[i].t <= tb + 1e-6) { sn = &snaps[i]; break; }
                    if (sn && tb - sn->t < 0.005) {
                        double er = t.enc_r - sn->s_r, el = t.enc_l - sn->s_l;
                        if (fabs(er) > enc_err_max[0]) enc_err_max[0] = fabs(er);
                        if (fabs(el) > enc_err_max[1]) enc_err_max[1] = fabs(el);
                        if (t.enc_r != sn->pins_r || t.enc_l != sn->pins_l) ++enc_pin_mismatch;
                        double lag = tb - sn->t;
                        if (lag > snap_lag_max) snap_lag_max = lag;
                        ++enc_checked;
                    }
                }
            }
        } else if (f.type == proto::kMsgParams) {
            ++params_frames;
        } else if (f.type == proto::kMsgAck) {
            ++ack_frames;
        }
    }
    bool flipped, dropped;
    uint8_t c = corrupt(b, &flipped, &dropped, opt.link_up);
    ++link.up_bytes;
    if (dropped) { ++link.up_dropped; return; }
    if (flipped) ++link.up_flipped;
    if (pty_fd >= 0) {
        ssize_t n = write(pty_fd, &c, 1);
        if (n != 1) ++link.up_unsent;  // host not reading (pty buffer full) or not there
    }
}

// ------------------------------------------------------------------------ plant step
void pace() {
    if (opt.realtime <= 0) return;
    double target = wall_at_pace0 + (board_now() - sim_t_at_pace0) / opt.realtime;
    double now = wall_now();
    if (target > now + 0.001) {
        double d = target - now;
        struct timespec ts = {static_cast<time_t>(d), static_cast<long>((d - floor(d)) * 1e9)};
        nanosleep(&ts, nullptr);
    }
}

avr_cycle_count_t plant_cb(avr_t*, avr_cycle_count_t when, void*) {
    if (((avr->data[kPIND] ^ pins_driven) & 0x0F) && edges[0].empty() && edges[1].empty()) ++pin_conflicts;
    duty[0] = channel_duty(0);
    duty[1] = channel_duty(1);
    const slip::PlantState& s = plant.state();
    double s0r = s.theta_r_rad * counts_per_rad(), s0l = s.theta_l_rad * counts_per_rad();
    double t0 = board_t(when);
    double x0 = s.x_m, y0 = s.y_m, p0 = s.phi_rad;
    plant.step_duty(duty[0], duty[1], opt.plant_dt);
    const slip::PlantState& s1 = plant.state();
    double t1 = board_t(when + plant_cycles);
    step_c0 = when;
    step_s0[0] = s0r;
    step_s0[1] = s0l;
    step_s1[0] = s1.theta_r_rad * counts_per_rad();
    step_s1[1] = s1.theta_l_rad * counts_per_rad();
    schedule_edges(0, s0r, s1.theta_r_rad * counts_per_rad(), when, plant_cycles);
    schedule_edges(1, s0l, s1.theta_l_rad * counts_per_rad(), when, plant_cycles);
    arm_edges(0);
    arm_edges(1);
    if (s1.slipping_r) ++steps_slipping[0];
    if (s1.slipping_l) ++steps_slipping[1];
    // longitudinal slip speed of each contact point: r theta_dot - (v +- b omega), right at -b y
    double vs[2] = {s1.dtheta_r_rad_s * plant.robot().r - (s1.v_m_s + plant.robot().b * s1.omega_rad_s),
                    s1.dtheta_l_rad_s * plant.robot().r - (s1.v_m_s - plant.robot().b * s1.omega_rad_s)};
    for (double v : vs)
        if (fabs(v) > max_slip_speed) max_slip_speed = fabs(v);
    if (board_origin_set) {
        camera(t0, x0, y0, p0, t1, s1.x_m, s1.y_m, s1.phi_rad);
        if (plant_steps % static_cast<unsigned long>(opt.plant_log_every) == 0) write_plant_row(s1, t1);
    }
    ++plant_steps;
    if (!poll_host() && opt.exit_on_hangup) { stop_now = true; stop_reason = "host closed the link"; }
    bool hang_due = (opt.hang_at >= 0 && board_now() >= opt.hang_at) ||
                    (opt.hang_after_run >= 0 && run_start_t >= 0 && board_now() >= run_start_t + opt.hang_after_run);
    if (hang_due && !hang_done && board_origin_set) {
        avr->data[hang_addr] = 1;
        hang_done = true;
        hang_t = board_now();
    }
    if ((plant_steps & 15) == 0) pace();
    next_plant_at = when + plant_cycles;
    return next_plant_at;
}

// ---------------------------------------------------------------------------- stepping
void step() {
    avr_flashaddr_t pc0 = avr->pc;
    uint16_t op = static_cast<uint16_t>(avr->flash[pc0] | (avr->flash[pc0 + 1] << 8));
    avr_run(avr);
    if (static_cast<long>(avr->pc) == snap_pc && board_origin_set) {
        Snap sn{board_now(), counts_at(0, avr->cycle), counts_at(1, avr->cycle), pos_now[0], pos_now[1]};
        snaps.push_back(sn);
        while (snaps.size() > 400) snaps.pop_front();
        ++snap_calls;
        if (snap_f) fprintf(snap_f, "%.7f,%.4f,%.4f,%ld,%ld,%u\n", sn.t, sn.s_r, sn.s_l, sn.pins_r, sn.pins_l,
                            static_cast<unsigned>(boot_at_s.size()));
    }
    if (op == 0x9518 && isr_depth > 0) {  // RETI
        if (avr->interrupt_state < -1) avr->interrupt_state = -1;  // hardware: one instruction
        Open& o = isr_stack[--isr_depth];
        avr_cycle_count_t total = avr->cycle - o.start;
        unsigned long d = static_cast<unsigned long>(total - o.nested);
        VecStat& v = vstat[o.vec];
        ++v.n;
        v.sum += static_cast<double>(d);
        if (d > v.max) v.max = d;
        if (isr_depth > 0) isr_stack[isr_depth - 1].nested += total;
    }
    if (avr->pc < kVecEnd && avr->pc != 0 && pc0 >= kVecEnd) {  // the core has just vectored
        if (isr_depth > 0) ++isr_nested_calls;
        if (isr_depth < 16) isr_stack[isr_depth++] = Open{static_cast<int>(avr->pc / 4), avr->cycle, 0};
        avr->cycle += 5;  // interrupt response that simavr does not charge
    }
}

void no_sleep(avr_t*, avr_cycle_count_t) {}

volatile sig_atomic_t got_signal;
void on_signal(int sig) { got_signal = sig; stop_now = 1; }  // pacing is ours (pace()), not simavr's usleep

void open_pty() {
    pty_fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (pty_fd < 0 || grantpt(pty_fd) || unlockpt(pty_fd)) die("cannot create a pty: %s", strerror(errno));
    const char* name = ptsname(pty_fd);
    if (!name) die("ptsname failed");
    pty_name = name;
    struct termios tio;
    int sfd = open(name, O_RDWR | O_NOCTTY);  // raw mode on the slave side, then let go
    if (sfd >= 0) {
        if (tcgetattr(sfd, &tio) == 0) {
            cfmakeraw(&tio);
            tcsetattr(sfd, TCSANOW, &tio);
        }
        close(sfd);
    }
    fcntl(pty_fd, F_SETFL, fcntl(pty_fd, F_GETFL) | O_NONBLOCK);
    if (!opt.pty_link.empty()) {
        unlink(opt.pty_link.c_str());
        if (symlink(name, opt.pty_link.c_str())) die("cannot make the symlink %s: %s", opt.pty_link.c_str(), strerror(errno));
    }
}

void json_str(FILE* f, const std::string& s) {
    fputc('"', f);
    for (char c : s) {
        if (c == '"' || c == '\\') fputc('\\', f);
        if (static_cast<unsigned char>(c) < 0x20) fprintf(f, "\\u%04x", c);
        else fputc(c, f);
    }
    fputc('"', f);
}

void write_summary(double wall_s) {
    std::string path = opt.run_dir + "/fil.json";
    FILE* f = fopen(path.c_str(), "w");
    if (!f) die("cannot write %s: %s", path.c_str(), strerror(errno));
    double sim_s = static_cast<double>(avr->cycle) / kF;
    fprintf(f, "{\n  \"format\": \"fil/1\",\n  \"elf\": ");
    json_str(f, opt.elf);
    fprintf(f, ",\n  \"stop_reason\": ");
    json_str(f, stop_reason);
    fprintf(f, ",\n  \"sim_s\": %.6f,\n  \"board_t_end_s\": %.6f,\n  \"wall_s\": %.3f,\n  \"wall_waiting_for_host_s\": %.3f,\n",
            sim_s, board_now(), wall_s, wall_waiting);
    double run_wall = wall_s - wall_waiting;
    fprintf(f, "  \"realtime_limit\": %g,\n  \"sim_s_per_wall_s\": %.4f,\n", opt.realtime,
            run_wall > 0 ? sim_s / run_wall : 0.0);
    fprintf(f, "  \"plant_dt_s\": %g,\n  \"plant_steps\": %lu,\n  \"plant_keys\": {", opt.plant_dt, plant_steps);
    for (size_t i = 0; i < opt.keys.size(); ++i) {
        fprintf(f, "%s", i ? ", " : "");
        json_str(f, opt.keys[i].first);
        fprintf(f, ": %.17g", opt.keys[i].second);
    }
    fprintf(f, "},\n");
    fprintf(f, "  \"isr_cycles\": {");
    bool first = true;
    for (int v = 0; v < 64; ++v) {
        if (!vstat[v].n) continue;
        fprintf(f, "%s\n    \"%d\": {\"calls\": %lu, \"max\": %lu, \"mean\": %.2f}", first ? "" : ",", v,
                vstat[v].n, vstat[v].max, vstat[v].sum / static_cast<double>(vstat[v].n));
        first = false;
    }
    fprintf(f, "\n  },\n  \"isr_nested_calls\": %lu,\n", isr_nested_calls);
    VecStat enc;
    for (int v = 1; v <= 4; ++v) {
        enc.n += vstat[v].n;
        enc.sum += vstat[v].sum;
        if (vstat[v].max > enc.max) enc.max = vstat[v].max;
    }
    fprintf(f, "  \"encoder_isr\": {\"edges_driven\": %lu, \"calls\": %lu, \"max_cycles\": %lu, \"mean_cycles\": %.2f},\n",
            edges_total[0] + edges_total[1], enc.n, enc.max, enc.n ? enc.sum / static_cast<double>(enc.n) : 0.0);
    // the firmware resets its task statistics at Start: "experiment" = frames with status running
    const char* tn[3] = {"inner", "outer", "telemetry"};
    fprintf(f, "  \"tasks\": {");
    for (int i = 0; i < 3; ++i)
        fprintf(f, "%s\"%s\": {\"max_cycles\": %u, \"overruns\": %u, \"experiment_max_cycles\": %u, "
                   "\"experiment_overruns\": %u}", i ? ", " : "", tn[i], task_max[i], task_overruns_max[i],
                task_max_run[i], task_overruns_run[i]);
    fprintf(f, ", \"running_frames\": %lu},\n", running_frames);
    fprintf(f, "  \"encoder_check\": {\"frames\": %lu, \"max_abs_err_counts_r\": %.4f, \"max_abs_err_counts_l\": %.4f,"
               " \"illegal_max_r\": %u, \"illegal_max_l\": %u, \"jitter_us\": %g, \"glitch_p\": %g, \"pin_conflicts\": %lu,\n    \"snapshot_calls\": %lu, \"frames_counts_not_edges_driven\": %lu, \"max_snapshot_to_t_us_s\": %.7f},\n",
            enc_checked, enc_err_max[0], enc_err_max[1], illegal_max[0], illegal_max[1], opt.enc_jitter_us, opt.enc_glitch,
            pin_conflicts, snap_calls, enc_pin_mismatch, snap_lag_max);
    fprintf(f, "  \"slip\": {\"steps_slipping_r\": %lu, \"steps_slipping_l\": %lu, \"max_slip_speed_m_s\": %.6f},\n",
            steps_slipping[0], steps_slipping[1], max_slip_speed);
    const slip::PlantState& s = plant.state();
    fprintf(f, "  \"final_pose\": {\"x_m\": %.6f, \"y_m\": %.6f, \"phi_rad\": %.6f, \"theta_r_rad\": %.6f, \"theta_l_rad\": %.6f},\n",
            s.x_m, s.y_m, s.phi_rad, s.theta_r_rad, s.theta_l_rad);
    auto list = [&](const char* name, const std::vector<double>& v) {
        fprintf(f, "  \"%s\": [", name);
        for (size_t i = 0; i < v.size(); ++i) fprintf(f, "%s%.6f", i ? ", " : "", v[i]);
        fprintf(f, "],\n");
    };
    list("brake_on_t_s", brake_on_t);
    list("brake_off_t_s", brake_off_t);
    list("boot_t_s", boot_at_s);
    list("reset_t_s", reset_at_s);
    fprintf(f, "  \"failsafe_events\": [");
    for (size_t i = 0; i < failsafe_events.size(); ++i)
        fprintf(f, "%s{\"t_s\": %.6f, \"code\": %u, \"boot\": %u}", i ? ", " : "", failsafe_events[i].t,
                failsafe_events[i].code, failsafe_events[i].boot);
    fprintf(f, "],\n  \"reset_causes\": [");
    for (size_t i = 0; i < reset_causes.size(); ++i)
        fprintf(f, "%s{\"t_s\": %.6f, \"mcusr\": %u}", i ? ", " : "", reset_causes[i].first, reset_causes[i].second);
    fprintf(f, "],\n  \"experiment_start_t_s\": %.6f,\n  \"hang\": {\"at_s\": %g, \"after_start_s\": %g, \"set_t_s\": %.6f, \"symbol_addr\": %ld},\n",
            run_start_t, opt.hang_at, opt.hang_after_run, hang_t, hang_addr);
    fprintf(f, "  \"frames_from_robot\": {\"telemetry\": %lu, \"params\": %lu, \"ack\": %lu, \"seq_restarts\": %lu},\n",
            telem_frames, params_frames, ack_frames, seq_restarts);
    fprintf(f, "  \"link\": {\"pty\": ");
    json_str(f, pty_name);
    fprintf(f, ", \"baud\": %.1f, \"ber\": %g, \"drop\": %g, \"up\": %s, \"down\": %s,\n"
               "    \"up_bytes\": %lu, \"up_flipped\": %lu, \"up_dropped\": %lu, \"up_unsent\": %lu,\n"
               "    \"down_bytes\": %lu, \"down_flipped\": %lu, \"down_dropped\": %lu, \"down_silenced\": %lu,\n"
               "    \"host_silent_at_s\": %g, \"host_silent_after_start_s\": %g, \"last_down_byte_t_s\": %.6f, \"last_down_frame_t_s\": %.6f,\n"
               "    \"down_frames\": %lu, \"down_frames_corrupted\": %lu, \"down_corrupted_seqs\": [",
            kF / (8.0 * (XBEE_UBRR + 1)), opt.link_ber, opt.link_drop, opt.link_up ? "true" : "false",
            opt.link_down ? "true" : "false", link.up_bytes, link.up_flipped, link.up_dropped, link.up_unsent,
            link.down_bytes, link.down_flipped, link.down_dropped, link.down_silenced, opt.host_silent_at, opt.silent_after_run,
            link.last_down_byte_t, link.last_down_frame_t, down_frames_total, down_frames_corrupted);
    for (size_t i = 0; i < down_corrupted_seqs.size(); ++i) fprintf(f, "%s%u", i ? ", " : "", down_corrupted_seqs[i]);
    fprintf(f, "]},\n  \"groundtruth\": {\"rate_hz\": %g, \"noise_xy_m\": %g, \"noise_phi_rad\": %g, \"dropout\": %g, "
               "\"rows\": %lu, \"missing\": %lu},\n",
            opt.cam_rate, opt.cam_xy, opt.cam_phi, opt.cam_dropout, gt_rows, gt_missing);
    fprintf(f, "  \"pwm_model\": \"%s\",\n  \"seed\": %u\n}\n", opt.pwm_ideal ? "ideal" : "hardware", opt.seed);
    fclose(f);
}

}  // namespace

int main(int argc, char** argv) {
    parse(argc, argv);
    rng.seed(opt.seed);
    for (const auto& kv : opt.keys) {
        int r = slip::plant_set(plant, kv.first.c_str(), kv.second);
        if (r == slip::kKeyUnknown) die("--set: unknown plant key '%s'", kv.first.c_str());
        if (r != slip::kKeyOk) die("--set: bad value for '%s'", kv.first.c_str());
    }
    plant.reset(0, 0, 0);
    plant_cycles = static_cast<avr_cycle_count_t>(llround(opt.plant_dt * kF));
    if (mkdir(opt.run_dir.c_str(), 0777) && errno != EEXIST) die("cannot create %s: %s", opt.run_dir.c_str(), strerror(errno));
    std::string gp = opt.run_dir + "/groundtruth.csv", pp = opt.run_dir + "/plant.csv";
    if (access(gp.c_str(), F_OK) == 0) die("%s already exists; refusing to overwrite a recorded run", gp.c_str());
    gt_f = fopen(gp.c_str(), "w");
    plant_f = fopen(pp.c_str(), "w");
    snap_f = fopen((opt.run_dir + "/encoder_samples.csv").c_str(), "w");
    if (!gt_f || !plant_f || !snap_f) die("cannot write in %s: %s", opt.run_dir.c_str(), strerror(errno));
    fprintf(gt_f, "t_s,x_m,y_m,phi_rad\n");
    fprintf(snap_f, "t_s,counts_true_r,counts_true_l,edges_driven_r,edges_driven_l,boot\n");
    fprintf(plant_f, "t_s,x_m,y_m,phi_rad,v_m_s,w_m_s,omega_rad_s,theta_r_rad,theta_l_rad,dtheta_r_rad_s,"
                     "dtheta_l_rad_s,duty_r,duty_l,tau_r_nm,tau_l_nm,slipping_r,slipping_l,enc_pins_r,enc_pins_l,"
                     "counts_true_r,counts_true_l\n");

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (access(opt.elf.c_str(), R_OK)) die("cannot read %s: %s", opt.elf.c_str(), strerror(errno));
    if (elf_read_firmware(opt.elf.c_str(), &fw)) die("libsimavr cannot load %s", opt.elf.c_str());
    if (opt.hang_at >= 0 || opt.hang_after_run >= 0) {
        hang_addr = elf_symbol(opt.elf.c_str(), "g_fault_hang");
        if (hang_addr < 0) die("--hang-at/--hang-after-start: %s has no symbol g_fault_hang (the firmware's hang hook)", opt.elf.c_str());
        hang_addr &= 0xFFFF;  // data space offset
    }
    snap_pc = elf_symbol(opt.elf.c_str(), "_Z12enc_snapshotv");
    if (snap_pc < 0) fprintf(stderr, "fil: warning: no enc_snapshot() in %s: no encoder check\n", opt.elf.c_str());
    avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) die("libsimavr has no atmega2560");
    avr_init(avr);
    avr->frequency = static_cast<uint32_t>(kF);
    avr->log = 0;
    avr_load_firmware(avr, &fw);
    avr->sleep = no_sleep;
    // INT4..INT7 (PE4..PE7) are never enabled by the firmware (EIMSK |= 0x0F), but their sense
    // control stays at 00 (low level) and PE5 is the right motor's PWM pin: simavr's "strict"
    // low-level emulation then polls the pin on every cycle while it is low (motors off), which
    // made the simulation ~2-3x slower. Non-strict: no polling; the disabled vectors are unaffected.
    for (uint8_t i = 4; i < 8; ++i) avr_extint_set_strict_lvl_trig(avr, i, 0);
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('2'), &flags);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('2'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('2'), UART_IRQ_OUTPUT), on_uart_out, nullptr);
    for (int i = 0; i < 4; ++i) {
        pin_irq[i] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), i);
        avr_raise_irq(pin_irq[i], 1);  // kPhase0: both channels high
    }
    byte_cycles = static_cast<avr_cycle_count_t>(llround(10.0 * 8.0 * (XBEE_UBRR + 1)));  // 10 bits at U2X baud
    open_pty();
    printf("PTY %s\n", pty_name.c_str());
    fflush(stdout);

    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    clock_gettime(CLOCK_MONOTONIC, &wall0);
    next_plant_at = plant_cycles;
    avr_cycle_timer_register(avr, plant_cycles, plant_cb, nullptr);
    bool waited = !opt.wait_host;
    for (;;) {
        step();
        if (avr->state == cpu_Crashed || avr->state == cpu_Done) {
            stop_reason = avr->state == cpu_Crashed ? "firmware crashed (simavr cpu_Crashed)" : "firmware stopped";
            break;
        }
        bool br = (avr->data[kPORTH] & 0x60) == 0x60;  // both BRAKE pins high, at the exact cycle
        if (br != braking) {
            (br ? brake_on_t : brake_off_t).push_back(board_now());
            braking = br;
        }
        bool t5 = avr->data[kTCCR5B] != 0;
        if (t5 && !board_running) {
            board_running = true;
            if (!board_origin_set) { board_origin = avr->cycle; board_origin_set = true; next_cam_t = 0; }
            boot_at_s.push_back(board_now());
        } else if (!t5 && board_running) {
            board_running = false;
            isr_depth = 0;  // a reset abandons any ISR in progress
            reset_at_s.push_back(board_now());
        }
        if (avr->cycle > next_plant_at + plant_cycles) {  // a reset cleared the cycle timers
            next_plant_at = avr->cycle;
            avr_cycle_timer_register(avr, 0, plant_cb, nullptr);
            edge_armed[0] = edge_armed[1] = false;
            arm_edges(0);
            arm_edges(1);
            if (!down_q.empty()) { avr_cycle_timer_register(avr, byte_cycles, down_cb, nullptr); down_armed = true; }
            else down_armed = false;
        }
        if (!waited && board_origin_set && board_now() >= opt.boot_s) {
            waited = true;
            double w0 = wall_now();
            while (!host_seen) {
                poll_host();
                if (host_seen || stop_now) break;
                if (wall_now() - w0 > opt.host_wait_s) {
                    stop_reason = "no host byte within --host-wait";
                    stop_now = true;
                    break;
                }
                usleep(5000);
            }
            wall_waiting = wall_now() - w0;
            sim_t_at_pace0 = board_now();
            wall_at_pace0 = wall_now();
        }
        if (stop_now) {
            if (got_signal) stop_reason = got_signal == SIGINT ? "interrupted (SIGINT)" : "terminated (SIGTERM)";
            break;
        }
        if (board_origin_set && board_now() >= opt.t_end) break;
    }
    double wall_s = wall_now();
    fclose(gt_f);
    fclose(plant_f);
    fclose(snap_f);
    write_summary(wall_s);
    if (pty_fd >= 0) close(pty_fd);
    if (!opt.pty_link.empty()) unlink(opt.pty_link.c_str());
    fprintf(stderr, "fil: %s at board time %.3f s; %.3f simulated s per wall s\n", stop_reason.c_str(), board_now(),
            (wall_s - wall_waiting) > 0 ? (static_cast<double>(avr->cycle) / kF) / (wall_s - wall_waiting) : 0.0);
    return avr->state == cpu_Crashed ? 1 : 0;
}
