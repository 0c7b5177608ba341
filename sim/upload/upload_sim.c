/*
 * upload_sim: an Arduino Mega 2560 as avrdude sees it, in libsimavr.
 *
 *   flash     erased, with a bootloader image (Intel HEX, e.g. Debian arduino-core-avr's
 *             stk500boot_v2_mega2560.hex) written where the HEX says;
 *   fuses     --hfuse (and --lfuse, --efuse) as the board's fuses: BOOTRST programmed (bit 0 = 0)
 *             puts the reset vector at the start of the boot section that BOOTSZ (bits 2:1) sizes
 *             (ATmega640/1280/2560 datasheet, "Boot Size Configuration"); else at 0;
 *   USART0    <-> a pseudo-terminal, the board's USB serial port. Opening it resets the MCU (an
 *             external reset, MCUSR.EXTRF), as the Mega's DTR auto-reset does when a host opens
 *             the port; host bytes reach the USART at the line rate the USART is set to;
 *   USART2    <-> a second pseudo-terminal: the XBee link (include/board.h), where the firmware
 *             sends its telemetry.
 * The core is stepped with sim/common's corrections (avrsim_step) and paced to the wall clock
 * (avrdude's time-outs are wall time; the bootloader's own wait is counted in cycles).
 *
 * Prints "UART0 /dev/pts/N", "UART2 /dev/pts/M", then one line per event: "RESET t=..."
 * (the port was opened), "APP t=..." (the core jumped from the boot section to address 0).
 * Stops on SIGTERM/SIGINT or after --t-max wall seconds; --flash-out writes the whole flash
 * (binary) at the end.
 *
 * Usage: upload_sim --boot HEX --hfuse 0xD8 [--lfuse 0xFF] [--efuse 0xFD] [--uart0-link PATH]
 *                   [--uart2-link PATH] [--flash-out FILE] [--t-max S] [--realtime X]
 */
#define _GNU_SOURCE /* posix_openpt, ptsname */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_cycle_timers.h>
#include <simavr/sim_irq.h>

#include "avrsim.h"
#include "board_sim.h" /* register names: include last */

#define FLASH_BYTES (FLASHEND + 1UL)
#define QUEUE_BYTES 65536

static volatile sig_atomic_t g_signal;
static void on_signal(int sig) { g_signal = sig; }

static void die(const char *fmt, const char *a) {
    fprintf(stderr, "upload_sim: error: ");
    fprintf(stderr, fmt, a);
    fprintf(stderr, "\n");
    exit(2);
}

/* ------------------------------------------------------------------------- Intel HEX */
static int hexval(const char *s, int n, unsigned long *v) {
    *v = 0;
    for (int i = 0; i < n; ++i) {
        char c = s[i];
        int d = c >= '0' && c <= '9' ? c - '0' : c >= 'A' && c <= 'F' ? c - 'A' + 10 : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
        if (d < 0) return -1;
        *v = (*v << 4) | (unsigned long)d;
    }
    return 0;
}

/* Writes the HEX's data records into flash; returns the bytes written, lowest and highest
 * address (exits with a message on a malformed file). Records 00-05 (I8HEX, I16HEX, I32HEX). */
static unsigned long load_hex(const char *path, uint8_t *flash, unsigned long *lo, unsigned long *hi) {
    FILE *f = fopen(path, "r");
    if (!f) die("cannot read %s", path);
    char line[600];
    unsigned long base = 0, n = 0, row = 0;
    *lo = FLASH_BYTES;
    *hi = 0;
    while (fgets(line, sizeof line, f)) {
        ++row;
        size_t len = strcspn(line, "\r\n");
        if (len == 0) continue;
        unsigned long cnt, addr, type, b, sum = 0;
        if (line[0] != ':' || len < 11 || hexval(line + 1, 2, &cnt) || len != 11 + 2 * cnt ||
            hexval(line + 3, 4, &addr) || hexval(line + 7, 2, &type))
            die("%s: not an Intel HEX record", path);
        for (size_t i = 1; i + 2 < len; i += 2) { /* every byte but the checksum */
            hexval(line + i, 2, &b);
            sum += b;
        }
        if (hexval(line + len - 2, 2, &b) || ((sum + b) & 0xFF) != 0) die("%s: bad record checksum", path);
        (void)row;
        if (type == 0) {
            for (unsigned long i = 0; i < cnt; ++i) {
                unsigned long a = base + addr + i;
                if (a >= FLASH_BYTES) die("%s: data beyond the ATmega2560's flash", path);
                hexval(line + 9 + 2 * i, 2, &b);
                flash[a] = (uint8_t)b;
                if (a < *lo) *lo = a;
                if (a > *hi) *hi = a;
                ++n;
            }
        } else if (type == 1) {
            break;
        } else if (type == 2 || type == 4) {
            unsigned long seg;
            hexval(line + 9, 4, &seg);
            base = type == 2 ? seg << 4 : seg << 16;
        } else if (type != 3 && type != 5) {
            die("%s: unknown record type", path);
        }
    }
    fclose(f);
    if (n == 0) die("%s: no data", path);
    return n;
}

/* Byte address of the reset vector the fuses select (datasheet: BOOTRST, BOOTSZ1:0). */
static unsigned long reset_address(unsigned hfuse) {
    if (hfuse & 1u) return 0; /* BOOTRST unprogrammed: the application's reset vector */
    unsigned bootsz = (hfuse >> 1) & 3u;                 /* 11: 512 words ... 00: 4096 words */
    unsigned long words = 512UL << (3u - bootsz);
    return FLASH_BYTES - 2 * words;
}

/* ----------------------------------------------------------------------------- state */
typedef struct port {
    char digit;                 /* simavr's USART name */
    int fd;                     /* pty master */
    char name[128];
    avr_irq_t *in;
    uint8_t q[QUEUE_BYTES];     /* host bytes not yet shifted in */
    size_t q_head, q_len;
    int armed;
    int open;                   /* a host holds the slave side open */
    unsigned long up_bytes, down_bytes;
} port_t;

typedef struct sim {
    avrsim_t s;
    avr_t *avr;
    port_t p0, p2;
    unsigned long boot_pc;
    int in_boot;
    unsigned long resets, app_starts;
} sim_t;

static sim_t g;

static double wall_now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* 10 bit times (8N1) at the USART's current setting: UBRR and U2X as the firmware set them. */
static avr_cycle_count_t byte_cycles(const port_t *p) {
    uint16_t ubrr_addr = p->digit == '0' ? UBRR0 : UBRR2;
    uint16_t ucsra = p->digit == '0' ? UCSR0A : UCSR2A;
    unsigned u2x = p->digit == '0' ? U2X0 : U2X2;
    unsigned long ubrr = avrsim_rd16(&g.s, ubrr_addr) & 0x0FFFu;
    unsigned long per_bit = (ubrr + 1) * ((g.avr->data[ucsra] >> u2x) & 1u ? 8u : 16u);
    return (avr_cycle_count_t)(10u * per_bit);
}

static avr_cycle_count_t deliver(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr;
    port_t *p = (port_t *)param;
    if (p->q_len == 0) { p->armed = 0; return 0; }
    uint8_t b = p->q[p->q_head];
    p->q_head = (p->q_head + 1) % QUEUE_BYTES;
    --p->q_len;
    avr_raise_irq(p->in, b);
    ++p->down_bytes;
    return when + byte_cycles(p);
}

static void arm(port_t *p) {
    if (p->armed || p->q_len == 0) return;
    avr_cycle_timer_register(g.avr, byte_cycles(p), deliver, p);
    p->armed = 1;
}

static void on_output(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    port_t *p = (port_t *)param;
    uint8_t b = (uint8_t)value;
    ++p->up_bytes;
    if (p->open && write(p->fd, &b, 1) != 1) { /* host not reading: the byte is lost, as on a wire */ }
}

static void open_port(port_t *p, char digit, const char *link) {
    p->digit = digit;
    p->fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (p->fd < 0 || grantpt(p->fd) || unlockpt(p->fd)) die("cannot create a pty: %s", strerror(errno));
    const char *name = ptsname(p->fd);
    if (!name) die("ptsname failed%s", "");
    snprintf(p->name, sizeof p->name, "%s", name);
    int sfd = open(name, O_RDWR | O_NOCTTY); /* raw mode for hosts that do not set it */
    if (sfd >= 0) {
        struct termios tio;
        if (tcgetattr(sfd, &tio) == 0) {
            cfmakeraw(&tio);
            tcsetattr(sfd, TCSANOW, &tio);
        }
        close(sfd);
    }
    fcntl(p->fd, F_SETFL, fcntl(p->fd, F_GETFL) | O_NONBLOCK);
    if (link) {
        unlink(link);
        if (symlink(name, link)) die("cannot make the symlink %s", link);
    }
    uint32_t flags = 0; /* no stdio echo, no usleep() in status polls */
    avr_ioctl(g.avr, AVR_IOCTL_UART_SET_FLAGS(digit), &flags);
    p->in = avr_io_getirq(g.avr, AVR_IOCTL_UART_GETIRQ(digit), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(g.avr, AVR_IOCTL_UART_GETIRQ(digit), UART_IRQ_OUTPUT), on_output, p);
}

/* Whether a host holds the slave side open (the master reports POLLHUP while nobody does).
 * Returns 1 when the port went from closed to open. */
static int port_opened(port_t *p) {
    struct pollfd pf = {p->fd, POLLIN, 0};
    int was = p->open;
    if (poll(&pf, 1, 0) < 0) return 0;
    p->open = !(pf.revents & POLLHUP);
    return p->open && !was;
}

/* The bytes the host wrote, queued for the USART at its line rate. */
static void port_read(port_t *p) {
    uint8_t buf[512];
    for (;;) {
        ssize_t n = read(p->fd, buf, sizeof buf);
        if (n <= 0) break;
        for (ssize_t i = 0; i < n && p->q_len < QUEUE_BYTES; ++i) {
            p->q[(p->q_head + p->q_len) % QUEUE_BYTES] = buf[i];
            ++p->q_len;
        }
    }
    arm(p);
}

static double board_s(void) { return avrsim_seconds(g.avr->cycle); }

/* The host opened the USB serial port: DTR resets the MCU through the board's capacitor. */
static void external_reset(void) {
    avr_reset(g.avr); /* clears the I/O registers and simavr's cycle timers */
    avrsim_abandon_isrs(&g.s);
    g.avr->data[MCUSR] = (uint8_t)(1u << EXTRF);
    g.p0.armed = g.p2.armed = 0;
    g.p0.q_len = g.p2.q_len = 0; /* the USB-serial chip's buffer is flushed by the open */
    ++g.resets;
    g.in_boot = g.avr->pc >= g.boot_pc && g.boot_pc != 0;
    printf("RESET t=%.6f pc=0x%05lx\n", board_s(), (unsigned long)g.avr->pc);
    fflush(stdout);
}

int main(int argc, char **argv) {
    const char *boot = NULL, *link0 = NULL, *link2 = NULL, *flash_out = NULL;
    unsigned hfuse = 0x100, lfuse = 0xFF, efuse = 0xFD;
    double t_max = 600.0, realtime = 1.0;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        char *end = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            printf("usage: upload_sim --boot HEX --hfuse 0xD8 [--lfuse 0xFF] [--efuse 0xFD] [--uart0-link PATH]\n"
                   "                  [--uart2-link PATH] [--flash-out FILE] [--t-max WALL_S] [--realtime X]\n");
            return 0;
        }
        if (!v) die("%s needs a value", a);
        ++i;
        if (!strcmp(a, "--boot")) boot = v;
        else if (!strcmp(a, "--uart0-link")) link0 = v;
        else if (!strcmp(a, "--uart2-link")) link2 = v;
        else if (!strcmp(a, "--flash-out")) flash_out = v;
        else if (!strcmp(a, "--hfuse") || !strcmp(a, "--lfuse") || !strcmp(a, "--efuse")) {
            unsigned long x = strtoul(v, &end, 0);
            if (!end || *end || x > 0xFF) die("%s: not a fuse byte", v);
            *(!strcmp(a, "--hfuse") ? &hfuse : !strcmp(a, "--lfuse") ? &lfuse : &efuse) = (unsigned)x;
        } else if (!strcmp(a, "--t-max") || !strcmp(a, "--realtime")) {
            double x = strtod(v, &end);
            if (!end || *end || !(x >= 0)) die("%s: not a number >= 0", v);
            *(!strcmp(a, "--t-max") ? &t_max : &realtime) = x;
        } else die("unknown option %s", a);
    }
    if (!boot) die("--boot HEX is required%s", "");
    if (hfuse > 0xFF) die("--hfuse is required (the board's high fuse, e.g. 0xD8)%s", "");

    char err[256];
    if (avrsim_open_blank(&g.s, err, sizeof err)) die("%s", err);
    g.avr = g.s.avr;
    unsigned long lo, hi;
    unsigned long n = load_hex(boot, g.avr->flash, &lo, &hi);
    g.avr->fuse[0] = (uint8_t)lfuse;
    g.avr->fuse[1] = (uint8_t)hfuse;
    g.avr->fuse[2] = (uint8_t)efuse;
    g.boot_pc = reset_address(hfuse);
    g.avr->reset_pc = (avr_flashaddr_t)g.boot_pc;
    if (g.boot_pc && (lo < g.boot_pc || hi >= FLASH_BYTES))
        fprintf(stderr, "upload_sim: warning: the image (0x%05lx..0x%05lx) is not inside the boot section at 0x%05lx\n",
                lo, hi, g.boot_pc);
    avr_reset(g.avr); /* power on: pc at the fuses' reset vector */
    g.avr->data[MCUSR] = (uint8_t)(1u << PORF);
    g.in_boot = g.boot_pc != 0;

    open_port(&g.p0, '0', link0);
    open_port(&g.p2, '2', link2);
    printf("BOOT %lu bytes at 0x%05lx..0x%05lx, reset vector 0x%05lx (hfuse 0x%02X)\n", n, lo, hi, g.boot_pc, hfuse);
    printf("UART0 %s\nUART2 %s\n", g.p0.name, g.p2.name);
    fflush(stdout);

    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    const double wall0 = wall_now();
    const avr_cycle_count_t poll_every = AVRSIM_F_CPU_HZ / 2000; /* 0.5 ms */
    avr_cycle_count_t next_poll = 0;
    port_opened(&g.p0); /* the state at start: nobody has the port open yet */
    while (!g_signal) {
        avr_t *avr = g.avr;
        if (avr->cycle >= next_poll) {
            if (port_opened(&g.p0)) external_reset();
            port_opened(&g.p2);
            port_read(&g.p0);
            port_read(&g.p2);
            next_poll = avr->cycle + poll_every;
            avrsim_stop_at(&g.s, next_poll);
            double wall = wall_now() - wall0;
            if (wall > t_max) break;
            if (realtime > 0) {
                double ahead = board_s() / realtime - wall;
                if (ahead > 0.002) usleep((useconds_t)(ahead * 1e6));
            }
        }
        avrsim_step(&g.s);
        if (avr->state == cpu_Crashed || avr->state == cpu_Done) {
            fprintf(stderr, "upload_sim: the core stopped (state %d) at pc 0x%05lx\n", avr->state, (unsigned long)avr->pc);
            break;
        }
        if (g.in_boot && avr->pc == 0 && (g.avr->flash[0] != 0xFF || g.avr->flash[1] != 0xFF)) {
            g.in_boot = 0;
            ++g.app_starts;
            printf("APP t=%.6f\n", board_s());
            fflush(stdout);
        } else if (!g.in_boot && g.boot_pc && avr->pc >= g.boot_pc) {
            g.in_boot = 1;
        }
    }
    if (flash_out) {
        FILE *f = fopen(flash_out, "wb");
        if (!f || fwrite(g.avr->flash, 1, FLASH_BYTES, f) != FLASH_BYTES) die("cannot write %s", flash_out);
        fclose(f);
    }
    printf("END t=%.6f resets=%lu app_starts=%lu uart0_in=%lu uart0_out=%lu uart2_out=%lu\n", board_s(), g.resets,
           g.app_starts, g.p0.down_bytes, g.p0.up_bytes, g.p2.up_bytes);
    fflush(stdout);
    if (link0) unlink(link0);
    if (link2) unlink(link2);
    return 0;
}
