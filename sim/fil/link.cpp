// XBee link: USART2 <-> a pseudo-terminal at the line rate, byte corruption and loss in either
// direction, and a tap that decodes the robot's own frames for the measurements in fil.json.
#include "fil.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

extern "C" {
#include <simavr/avr_uart.h>
#include <simavr/sim_cycle_timers.h>
}

#include <protocol/messages.h>

namespace fil {


// USART2 at the XBee's line rate, host bytes in one by one (10 bits each), robot bytes out.
void Fil::setup_link() {
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS(SIM_XBEE_UART_DIGIT), &flags);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(SIM_XBEE_UART_DIGIT), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(SIM_XBEE_UART_DIGIT), UART_IRQ_OUTPUT),
                            [](avr_irq_t*, uint32_t value, void* p) { static_cast<Fil*>(p)->on_uart_out(value); },
                            this);
    byte_cycles = static_cast<avr_cycle_count_t>(llround(10.0 * 8.0 * (XBEE_UBRR + 1)));  // 10 bits at U2X baud
    open_pty();
}

void Fil::arm_down(avr_cycle_count_t in_cycles) {
    avr_cycle_timer_register(avr, in_cycles,
                             [](avr_t*, avr_cycle_count_t when, void* p) { return static_cast<Fil*>(p)->down_cb(when); },
                             this);
    down_armed = true;
}

// ------------------------------------------------------------------------ link (down)
uint8_t Fil::corrupt(uint8_t b, bool* flipped, bool* dropped, bool on) {
    *flipped = *dropped = false;
    if (!on) return b;
    if (opt.link_drop > 0 && uni(rng) < opt.link_drop) { *dropped = true; return b; }
    if (opt.link_ber > 0 && uni(rng) < opt.link_ber) {
        *flipped = true;
        return static_cast<uint8_t>(b ^ (1u << static_cast<unsigned>(uni(rng) * 8) % 8));
    }
    return b;
}

avr_cycle_count_t Fil::down_cb(avr_cycle_count_t when) {
    if (down_q.empty()) { down_armed = false; return 0; }
    uint8_t b = down_q.front();
    down_q.pop_front();
    avr_raise_irq(uart_in, b);
    ++link.down_bytes;
    link.last_down_byte_t = board_now();
    if (down_after.feed(b) == proto::Decoder::kFrame) link.last_down_frame_t = board_now();
    return when + byte_cycles;
}

void Fil::host_byte(uint8_t b) {
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
        arm_down(byte_cycles);
    }
}

// Reads what the host wrote into the pty. Returns false when the host has hung up.
bool Fil::poll_host() {
    if (pty_fd < 0) return true;
    uint8_t buf[256];
    for (;;) {
        ssize_t n = read(pty_fd, buf, sizeof buf);
        if (n > 0) {
            host_seen = true;
            host_bytes_read += static_cast<unsigned long>(n);
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
void Fil::on_uart_out(uint32_t value) {
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
                last_telem_t = tb;
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
        else ++up_to_pty;
    }
}

void Fil::open_pty() {
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

}  // namespace fil
