// Encoder edge generation: quadrature edges on PD0..PD3 at the cycles the plant's wheel angles
// cross count boundaries (simavr cycle timers, so edges wake a sleeping core on time).
#include "fil.h"

#include <math.h>

extern "C" {
#include <simavr/avr_ioport.h>
#include <simavr/sim_cycle_timers.h>
}

namespace fil {

namespace {
const int kReversed[2] = {ENC_RIGHT_REVERSED, ENC_LEFT_REVERSED};
const uint8_t kGray[4] = {0, 1, 3, 2};  // (B,A)
const int kBit[2][2] = {{ENC_RIGHT_A_BIT, ENC_RIGHT_B_BIT}, {ENC_LEFT_A_BIT, ENC_LEFT_B_BIT}};  // ENC_PORT bits
}  // namespace

// The wheel angle in counts at any cycle inside the current plant step (linear).
double Fil::counts_at(int w, avr_cycle_count_t c) const {
    double f = (static_cast<double>(c) - static_cast<double>(step_c0)) / static_cast<double>(plant_cycles);
    if (f < 0) f = 0;
    if (f > 1) f = 1;
    return step_s0[w] + f * (step_s1[w] - step_s0[w]);
}
// The encoder outputs drive PD0..PD3. simavr 1.6 models the firmware's pull-ups (PORTD |= 0x0F
// in enc_init) by raising the input pins to 1, over any level driven from outside. The simulated
// encoders therefore start in the phase where both channels are high ((B,A) = 11, Gray index 2):
// the pull-up write changes nothing and the first edge is counted. After a watchdog reset the
// wheels stand at an arbitrary phase and the same write can move a low line to 1: counted as
// pin_conflicts in fil.json (the encoder check covers the first boot only).
namespace {
const int kPhase0 = 2;
}  // namespace

void Fil::setup_encoders() {
    for (int w = 0; w < 2; ++w)
        for (int ch = 0; ch < 2; ++ch) {
            pin_irq[w][ch] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(SIM_ENC_PORT_LETTER), kBit[w][ch]);
            avr_raise_irq(pin_irq[w][ch], 1);  // kPhase0: both channels high
        }
}

void Fil::drive_pins(int w, long pos) {
    long g = kReversed[w] ? -pos : pos;
    uint8_t s_old = kGray[static_cast<unsigned long>((kReversed[w] ? -pos_now[w] : pos_now[w]) + kPhase0) & 3u];
    uint8_t s = kGray[static_cast<unsigned long>(g + kPhase0) & 3u];
    for (int ch = 0; ch < 2; ++ch) {  // A, B
        const unsigned level = (s >> ch) & 1u, bit = 1u << kBit[w][ch];
        pins_driven = static_cast<uint8_t>(level ? (pins_driven | bit) : (pins_driven & ~bit));
        if (((s ^ s_old) >> ch) & 1u) avr_raise_irq(pin_irq[w][ch], level);
    }
    pos_now[w] = pos;
    ++edges_total[w];
}

avr_cycle_count_t Fil::edge_cb(int w) {
    while (!edges[w].empty() && edges[w].front().at <= avr->cycle) {
        drive_pins(w, edges[w].front().pos);
        edges[w].pop_front();
    }
    if (edges[w].empty()) { edge_armed[w] = false; return 0; }
    return edges[w].front().at;
}

void Fil::arm_edges(int w) {
    if (edge_armed[w] || edges[w].empty()) return;
    avr_cycle_count_t at = edges[w].front().at;
    avr_cycle_timer_register(avr, at > avr->cycle ? at - avr->cycle : 0,
                             [](avr_t*, avr_cycle_count_t, void* p) -> avr_cycle_count_t {
                                 EdgeTimer* t = static_cast<EdgeTimer*>(p);
                                 return t->fil->edge_cb(t->wheel);
                             },
                             &edge_timer[w]);
    edge_armed[w] = true;
}

// Count-boundary crossings of one wheel in [c0, c0 + n) as the angle goes s0 -> s1 (counts).
void Fil::schedule_edges(int w, double s0, double s1, avr_cycle_count_t c0, avr_cycle_count_t n) {
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

}  // namespace fil
