/*
 * Firmware in the loop: the real megaatmega2560 firmware.elf runs in libsimavr at
 * 16 MHz against lib/slipmodel's slip::Plant, in lockstep with simulated time.
 *
 *   plant      every --plant-dt (default 0.5 ms = 8000 cycles) a cycle timer reads the motor
 *              outputs (OCR3C/OCR1A, COM bits, DIR and BRAKE pins), converts them to signed duty
 *              and calls Plant::step_duty over the next interval.
 *   encoders   the wheel angle is interpolated linearly within each plant step; every crossing
 *              of a count boundary becomes one quadrature edge on PD0..PD3, scheduled as a
 *              simavr cycle timer at the cycle of the crossing (so edges wake a sleeping core
 *              at the right cycle, not once per step).
 *   current    the shield's sense outputs: at each ADC conversion's sample instant, A0/A1 get
 *              |armature current| (the plant's) x protocol.json's volts per ampere.
 *   XBee       USART2 <-> a pseudo-terminal (its path is printed: "PTY /dev/pts/N"); the host
 *              sees the same bytes as from the radio. Host bytes are delivered at the line
 *              rate (10 bits per byte at the USART's actual baud rate).
 *   recording  groundtruth.csv (camera model), plant.csv (true plant state), adc_samples.csv, fil.json
 *              (measurements, link statistics) in --run-dir, all on the board clock (Timer5,
 *              which the firmware's time_us() counts, started at its first boot).
 * Interrupt timing: sim/common's corrections (avrsim_step), as in sim/isr_bench.
 * Usage: fil FIRMWARE.elf --run-dir DIR [options]   (fil --help)
 *
 * Files, one concern each, all state in struct Fil:
 *   options.cpp   command line            avr.cpp       libsimavr set-up, stepping, board clock
 *   plant.cpp     plant coupling, pacing  encoders.cpp  quadrature edges from the wheel angles
 *   link.cpp      XBee link (pty, USART2, corruption, telemetry tap)
 *   sense.cpp     current sense (ADC inputs A0/A1)
 *   recorder.cpp  groundtruth.csv, plant.csv, encoder_samples.csv, fil.json
 *   lockstep.cpp  --lockstep: the host's control lines on stdin hold the board clock
 *   main.cpp      the run loop
 */
#ifndef SIM_FIL_FIL_H
#define SIM_FIL_FIL_H

#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <time.h>

#include <deque>
#include <random>
#include <string>
#include <utility>
#include <vector>

extern "C" {
#include <simavr/sim_avr.h>
#include <simavr/sim_irq.h>
}

#include <protocol/frame.h>
#include <slipmodel/plant.h>

#include "avrsim.h"
#include "board_sim.h"  // wiring (board.h) and register names (avr-libc): include last

namespace fil {

const double kF = AVRSIM_F_CPU_HZ;
const double kTwoPi = 6.283185307179586;

[[noreturn]] void die(const char* fmt, const char* a = "", const char* b = "");

// ------------------------------------------------------------------------------ options
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
    std::string cam_unix_csv;      // also write the camera samples stamped with the host's Unix clock
    double enc_jitter_us = 0.0, enc_glitch = 0.0;
    double link_ber = 0.0, link_drop = 0.0;
    bool link_up = true, link_down = true;
    double host_silent_at = -1.0;  // board time after which host bytes are discarded
    double hang_at = -1.0;         // board time at which g_fault_hang is set
    double silent_after_run = -1.0, hang_after_run = -1.0;  // ... relative to the experiment start
    unsigned seed = 1;
    int plant_log_every = 1;
    bool pwm_ideal = false;        // duty = OCR / (TOP + 1) instead of the hardware's (OCR + 1) / (TOP + 1)
    bool lockstep = false;         // stdin carries the host's control lines (lockstep.cpp)
};

void usage();
void parse(Options& opt, int argc, char** argv);

// ---------------------------------------------------------------------------- the state
struct Fil;
struct EdgeTimer { Fil* fil; int wheel; };  // simavr cycle-timer parameter of one wheel's edges
struct Snap { double t, s_r, s_l; long pins_r, pins_l; };
struct Edge { avr_cycle_count_t at; long pos; };
struct FsEvent { double t; unsigned code; unsigned boot; };
struct LinkStats {
    unsigned long up_bytes = 0, up_flipped = 0, up_dropped = 0, up_unsent = 0;
    unsigned long down_bytes = 0, down_flipped = 0, down_dropped = 0, down_silenced = 0;
    double last_down_byte_t = -1;   // board time the last delivered host byte finished
    double last_down_frame_t = -1;  // ... and the last one that completed a valid frame
};

struct Fil {
    Fil() = default;
    Fil(const Fil&) = delete;  // edge_timer points into it
    Fil& operator=(const Fil&) = delete;
    Options opt;
    std::mt19937_64 rng;
    std::uniform_real_distribution<double> uni{0.0, 1.0};
    std::normal_distribution<double> gauss{0.0, 1.0};
    bool stop_now = false;
    std::string stop_reason = "t_end reached";

    // avr.cpp: the simulated core (ISR accounting in sim.isr) and the board clock
    avrsim_t sim;
    avr_t* avr = nullptr;
    bool board_running = false;
    bool board_origin_set = false;  // Timer5 start of the first boot
    avr_cycle_count_t board_origin = 0;
    std::vector<double> boot_at_s, reset_at_s;  // board times of timer starts / resets
    long hang_addr = -1;  // hang injection: g_fault_hang
    bool hang_done = false;
    double hang_t = -1;
    void setup_avr();
    void step();
    void after_step();  // board clock, brake times, re-arming the timers after a reset
    double board_t(avr_cycle_count_t c) const;
    double board_now() const;

    // plant.cpp: the plant against the motor outputs, pacing
    slip::Plant plant;
    avr_cycle_count_t plant_cycles = 0;
    avr_cycle_count_t next_plant_at = 0;  // cycle of the next plant step (timer re-armed after a reset)
    unsigned long plant_steps = 0;
    double duty[2] = {0, 0};
    bool braking = true;
    std::vector<double> brake_on_t, brake_off_t;
    unsigned long steps_slipping[2] = {0, 0};
    double max_slip_speed = 0;
    struct timespec wall0 = {0, 0};
    double sim_t_at_pace0 = 0, wall_at_pace0 = 0, wall_waiting = 0;
    double channel_duty(int w);
    void arm_plant(avr_cycle_count_t in_cycles);
    avr_cycle_count_t plant_cb(avr_cycle_count_t when);
    void pace();
    double wall_now() const;

    // encoders.cpp (index 0 = right, 1 = left)
    avr_irq_t* pin_irq[2][2] = {{nullptr, nullptr}, {nullptr, nullptr}};  // [wheel][A, B] on ENC_PORT
    EdgeTimer edge_timer[2] = {{this, 0}, {this, 1}};
    avr_cycle_count_t step_c0 = 0;  // the current plant step, for the wheel angle at any cycle inside it
    double step_s0[2] = {0, 0}, step_s1[2] = {0, 0};  // counts (angle * CPR / 2 pi) at its start and end
    std::deque<Edge> edges[2];
    bool edge_armed[2] = {false, false};
    long pos_now[2] = {0, 0};  // quadrature position currently driven on the pins (counts, + forward)
    long edges_total[2] = {0, 0};
    uint8_t pins_driven = ENC_MASK;  // ENC_PORT's encoder bits as driven by the encoders
    unsigned long pin_conflicts = 0;
    long snap_pc = -1;  // enc_snapshot(): the instants the firmware samples its counters
    std::deque<Snap> snaps;
    unsigned long snap_calls = 0;
    double counts_at(int w, avr_cycle_count_t c) const;
    void setup_encoders();  // the lines' simavr IRQs, driven high (both channels: phase 0)
    void drive_pins(int w, long pos);
    avr_cycle_count_t edge_cb(int w);
    void arm_edges(int w);
    void schedule_edges(int w, double s0, double s1, avr_cycle_count_t c0, avr_cycle_count_t n);

    // link.cpp: USART2 <-> pty, corruption, and the tap on the robot's own frames
    avr_irq_t* uart_in = nullptr;
    int pty_fd = -1;
    std::string pty_name;
    bool host_seen = false;
    std::deque<uint8_t> down_q;  // host bytes waiting to be shifted into USART2
    bool down_armed = false;
    avr_cycle_count_t byte_cycles = 0;
    LinkStats link;
    proto::Decoder down_clean;  // host stream before corruption: which frames were corrupted
    bool down_frame_dirty = false;
    std::vector<unsigned> down_corrupted_seqs;
    unsigned long down_frames_total = 0, down_frames_corrupted = 0;
    proto::Decoder down_after;  // what the robot received (complete, valid frames)
    proto::Decoder up_dec;      // the robot's bytes before link corruption
    unsigned long telem_frames = 0, params_frames = 0, ack_frames = 0;
    double enc_err_max[2] = {0, 0};
    unsigned long enc_pin_mismatch = 0;  // frames whose counts differ from the edges driven at the snapshot
    double snap_lag_max = 0;
    unsigned long enc_checked = 0;
    uint32_t task_max[3] = {0, 0, 0}, task_max_run[3] = {0, 0, 0};  // whole run / frames with status "running"
    unsigned task_overruns_max[3] = {0, 0, 0}, task_overruns_run[3] = {0, 0, 0};
    unsigned long running_frames = 0;
    double run_start_t = -1;  // board time of the first frame reporting an experiment running
    double last_telem_t = -1;  // board time stamp of the last whole telemetry frame the robot sent
    unsigned illegal_max[2] = {0, 0};
    uint8_t last_failsafe = 0;
    std::vector<FsEvent> failsafe_events;
    std::vector<std::pair<double, unsigned>> reset_causes;  // first frame of every boot
    unsigned telem_boot = 0;
    uint16_t last_seq = 0;
    bool have_seq = false;
    unsigned long seq_restarts = 0;
    void setup_link();
    void open_pty();
    uint8_t corrupt(uint8_t b, bool* flipped, bool* dropped, bool on);
    void arm_down(avr_cycle_count_t in_cycles);
    avr_cycle_count_t down_cb(avr_cycle_count_t when);
    void host_byte(uint8_t b);
    bool poll_host();
    void on_uart_out(uint32_t value);

    // sense.cpp: the shield's current sense (A0 right, A1 left) through the ADC
    FILE* adc_f = nullptr;  // adc_samples.csv
    unsigned long adc_samples = 0;
    double sense_max_a[2] = {0, 0};
    void setup_sense();
    void sense_sample(int channel, avr_cycle_count_t when);

    // lockstep.cpp (--lockstep): while stepping, the board clock runs only up to the host's grant
    // and host bytes are read only at the holds, so they reach USART2 at board times the host chose
    bool stepping = false;
    double grant_t = 0;                 // board time of the next hold
    unsigned long host_bytes_read = 0;  // bytes read from the pty so far (every one, silenced too)
    unsigned long up_to_pty = 0;        // robot bytes written into the pty so far (the host's to read)
    unsigned long holds = 0;
    std::string ctl_buf;                // stdin bytes not yet a whole line
    void setup_lockstep();
    double wait_host_connected();      // before the first cycle: the host has written
    void poll_control();                // free running: a "hold" line enters stepping (held from the start)
    bool at_grant() const { return stepping && board_origin_set && board_now() >= grant_t; }
    void hold(volatile sig_atomic_t* signal_flag);  // at the grant: report, wait for the next line

    // recorder.cpp
    FILE* gt_f = nullptr;
    FILE* gt_unix_f = nullptr;  // --cam-unix-csv: the same samples, stamped when made (CLOCK_REALTIME)
    FILE* plant_f = nullptr;
    FILE* snap_f = nullptr;
    double next_cam_t = 0;
    unsigned long gt_rows = 0, gt_missing = 0;
    void open_recording();
    void close_recording();
    void write_plant_row(const slip::PlantState& s, double t);
    void camera(double t0, double x0, double y0, double p0, double t1, double x1, double y1, double p1);
    void write_summary(double wall_s);

    double counts_per_rad() const { return ENC_COUNTS_PER_REV / kTwoPi; }
};

}  // namespace fil

#endif  // SIM_FIL_FIL_H
