// fil: the run loop (what each part does: fil.h).
#include "fil.h"

#include <math.h>
#include <signal.h>
#include <unistd.h>

#include <slipmodel/keys.h>

namespace {
// The one file-scope variable: what a signal handler may set.
volatile sig_atomic_t g_signal;
void on_signal(int sig) { g_signal = sig; }  // pacing is ours (Fil::pace), not simavr's usleep
}  // namespace

int main(int argc, char** argv) {
    static fil::Fil f;  // large (decoders, statistics): not on the stack
    fil::parse(f.opt, argc, argv);
    const fil::Options& opt = f.opt;
    f.rng.seed(opt.seed);
    for (const auto& kv : opt.keys) {
        int r = slip::plant_set(f.plant, kv.first.c_str(), kv.second);
        if (r == slip::kKeyUnknown) fil::die("--set: unknown plant key '%s'", kv.first.c_str());
        if (r != slip::kKeyOk) fil::die("--set: bad value for '%s'", kv.first.c_str());
    }
    f.plant.reset(0, 0, 0);
    f.plant_cycles = static_cast<avr_cycle_count_t>(llround(opt.plant_dt * fil::kF));
    f.open_recording();
    f.setup_avr();
    f.setup_encoders();
    f.setup_sense();
    f.setup_link();
    f.setup_lockstep();
    printf("PTY %s\n", f.pty_name.c_str());
    fflush(stdout);

    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    clock_gettime(CLOCK_MONOTONIC, &f.wall0);
    double waited_before = f.wait_host_connected();
    f.next_plant_at = f.plant_cycles;
    f.arm_plant(f.plant_cycles);
    bool waited = !opt.wait_host;
    avr_t* avr = f.avr;
    for (;;) {
        f.step();
        if (avr->state == cpu_Crashed || avr->state == cpu_Done) {
            f.stop_reason = avr->state == cpu_Crashed ? "firmware crashed (simavr cpu_Crashed)" : "firmware stopped";
            break;
        }
        f.after_step();
        if (f.at_grant()) f.hold(&g_signal);
        if (!waited && f.board_origin_set && f.board_now() >= opt.boot_s) {
            waited = true;
            double w0 = f.wall_now();
            while (!f.host_seen) {
                f.poll_host();
                if (f.host_seen || f.stop_now || g_signal) break;
                if (f.wall_now() - w0 > opt.host_wait_s) {
                    f.stop_reason = "no host byte within --host-wait";
                    f.stop_now = true;
                    break;
                }
                usleep(5000);
            }
            f.wall_waiting = waited_before + f.wall_now() - w0;
            f.sim_t_at_pace0 = f.board_now();
            f.wall_at_pace0 = f.wall_now();
        }
        if (f.stop_now || g_signal) {
            if (g_signal) f.stop_reason = g_signal == SIGINT ? "interrupted (SIGINT)" : "terminated (SIGTERM)";
            break;
        }
        if (f.board_origin_set && f.board_now() >= opt.t_end) break;
    }
    double wall_s = f.wall_now();
    f.close_recording();
    f.write_summary(wall_s);
    if (f.pty_fd >= 0) close(f.pty_fd);
    if (!opt.pty_link.empty()) unlink(opt.pty_link.c_str());
    fprintf(stderr, "fil: %s at board time %.3f s; %.3f simulated s per wall s\n", f.stop_reason.c_str(), f.board_now(),
            (wall_s - f.wall_waiting) > 0 ? (static_cast<double>(avr->cycle) / fil::kF) / (wall_s - f.wall_waiting) : 0.0);
    return avr->state == cpu_Crashed ? 1 : 0;
}
