// --lockstep: the host holds the board clock through control lines on stdin, so that a script
// of host bytes reaches the firmware at board times the host chose, whatever the host's own
// speed (a loaded machine, a stalled interpreter). Lines (ASCII, one per line):
//
//   run T N     (while held) wait until N host bytes in all have been read from the pty, then
//               run to board time T and hold again
//   free        (while held) run on, paced by --realtime as without --lockstep
//   hold G      (while free running) stop at the next board time that is a multiple of G s
//
// The simulator starts held: the firmware starts once the host has written into the pty (so the
// host receives all it sends), runs to 50 ms of board time (Options::boot_s) without reading a
// host byte, and holds there. Every board time from then on is the host's grant until it sends
// "free", so a host's script lands on the same board times in every run, whatever its speed.
// At every hold the simulator prints "AT <board time s> <host bytes read> <time stamp of the
// last whole telemetry frame the robot sent, s> <robot bytes written into the pty>" on stdout (a
// host that has read that many bytes has everything the robot sent before the hold). While
// stepping, the pty is read only at the holds: the host's bytes enter USART2's input queue at
// the hold's cycle, and no --realtime pacing applies (the host is the clock). The end of stdin
// ends the run (the host is gone).
#include "fil.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

namespace fil {

namespace {
const double kByteWaitS = 10.0;  // wall seconds a hold waits for the host bytes a "run" announced
}  // namespace

void Fil::setup_lockstep() {
    if (!opt.lockstep) return;
    fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);
    stepping = true;  // held from the start: the first hold at boot_s, before any host byte is read
    grant_t = opt.boot_s;
}

// Before the first cycle: wait until the host has written into the pty (it has opened it, so
// it receives the robot's first byte too), without reading: its bytes are read from 50 ms of
// board time on, as in every run. Returns the wall seconds waited.
double Fil::wait_host_connected() {
    if (!opt.lockstep || !opt.wait_host) return 0.0;
    double w0 = wall_now();
    for (;;) {
        struct pollfd p = {pty_fd, POLLIN, 0};
        if (poll(&p, 1, 20) > 0 && (p.revents & POLLIN)) break;
        if (wall_now() - w0 > opt.host_wait_s) {
            stop_now = true;
            stop_reason = "no host byte within --host-wait";
            break;
        }
    }
    return wall_now() - w0;
}

// Appends what stdin holds to ctl_buf. Returns false at the end of stdin.
static bool read_stdin(std::string& buf) {
    char b[256];
    for (;;) {
        ssize_t n = read(STDIN_FILENO, b, sizeof b);
        if (n > 0) { buf.append(b, static_cast<size_t>(n)); continue; }
        if (n == 0) return false;
        if (errno == EINTR) continue;
        return true;  // EAGAIN: nothing more now
    }
}

static bool next_line(std::string& buf, std::string* line) {
    size_t nl = buf.find('\n');
    if (nl == std::string::npos) return false;
    *line = buf.substr(0, nl);
    buf.erase(0, nl + 1);
    return true;
}

void Fil::poll_control() {
    if (!read_stdin(ctl_buf)) { stop_now = true; stop_reason = "the host closed the control channel (stdin)"; return; }
    std::string line;
    while (!stepping && next_line(ctl_buf, &line)) {
        double g = 0;
        if (sscanf(line.c_str(), "hold %lf", &g) == 1 && g > 0 && board_origin_set) {
            double t = ceil(board_now() / g - 1e-9) * g;
            grant_t = t;
            stepping = true;
        } else if (line != "free") {
            stop_now = true;
            stop_reason = "bad control line while free running: '" + line + "'";
            return;
        }
    }
}

void Fil::hold(volatile sig_atomic_t* signal_flag) {
    ++holds;
    printf("AT %.7f %lu %.6f %lu\n", board_now(), host_bytes_read, last_telem_t, up_to_pty);
    fflush(stdout);
    std::string line;
    for (;;) {
        if (*signal_flag || stop_now) return;
        if (next_line(ctl_buf, &line)) break;
        if (!read_stdin(ctl_buf)) { stop_now = true; stop_reason = "the host closed the control channel (stdin)"; return; }
        if (ctl_buf.find('\n') != std::string::npos) continue;
        struct pollfd p = {STDIN_FILENO, POLLIN, 0};
        poll(&p, 1, 100);
    }
    double t = 0;
    unsigned long n = 0;
    if (line == "free") {
        stepping = false;
        sim_t_at_pace0 = board_now();  // pacing starts again from here
        wall_at_pace0 = wall_now();
        return;
    }
    if (sscanf(line.c_str(), "run %lf %lu", &t, &n) != 2) {
        stop_now = true;
        stop_reason = "bad control line while held: '" + line + "'";
        return;
    }
    double w0 = wall_now();
    while (host_bytes_read < n) {  // the bytes the host wrote before this line: all of them now
        if (!poll_host() && opt.exit_on_hangup) { stop_now = true; stop_reason = "host closed the link"; return; }
        if (host_bytes_read >= n) break;
        if (*signal_flag) return;
        if (wall_now() - w0 > kByteWaitS) {
            stop_now = true;
            stop_reason = "lockstep: the host's announced bytes did not arrive";
            return;
        }
        struct pollfd p = {pty_fd, POLLIN, 0};
        poll(&p, 1, 10);
    }
    grant_t = t;
}

}  // namespace fil
