// Command line of fil (fil --help).
#include "fil.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>

namespace fil {

[[noreturn]] void die(const char* fmt, const char* a, const char* b) {
    fprintf(stderr, "fil: error: ");
    fprintf(stderr, fmt, a, b);
    fprintf(stderr, "\n");
    exit(2);
}

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
        "  --cam-unix-csv FILE  also write the samples as a tracker on the host would: t_s = the host's\n"
        "                       Unix time when each sample was made (the clock the logger stamps in)\n"
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
        "  --lockstep           stdin carries the host's control lines: 'hold G', 'run T N', 'free'\n"
        "                       (the board clock held between the host's grants; docs/fil.md)\n"
        "  --pwm-model hardware|ideal  fast PWM duty (OCR+1)/(TOP+1) as the ATmega2560 makes it\n"
        "                       (default), or OCR/(TOP+1) as the firmware's torque->PWM map assumes\n");
}

namespace {
double num(const char* s, const char* what) {
    char* end = nullptr;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end || !isfinite(v)) die("%s: not a number: '%s'", what, s);
    return v;
}

}  // namespace

void parse(Options& opt, int argc, char** argv) {
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
        else if (a == "--lockstep") opt.lockstep = true;
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
        else if (a == "--cam-unix-csv") opt.cam_unix_csv = val();
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

}  // namespace fil
