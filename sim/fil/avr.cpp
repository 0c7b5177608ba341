// avr/simavr glue: the firmware in libsimavr (sim/common's loader and corrected stepping), the
// board clock (Timer5, started at the first boot), resets, and the per-instruction hooks.
#include "fil.h"

#include <string.h>
#include <unistd.h>

extern "C" {
#include <simavr/avr_extint.h>
#include <simavr/sim_cycle_timers.h>
}

namespace fil {

double Fil::board_t(avr_cycle_count_t c) const {
    return (static_cast<double>(c) - static_cast<double>(board_origin)) / kF;
}
double Fil::board_now() const { return board_t(avr->cycle); }

void Fil::setup_avr() {
    const char* elf = opt.elf.c_str();
    if (access(elf, R_OK)) die("cannot read %s: %s", elf, strerror(errno));
    if (opt.hang_at >= 0 || opt.hang_after_run >= 0) {
        hang_addr = avrsim_data_symbol(elf, "g_fault_hang");
        if (hang_addr < 0) die("--hang-at/--hang-after-start: %s has no symbol g_fault_hang (the firmware's hang hook)", elf);
    }
    snap_pc = avrsim_symbol(elf, "_Z12enc_snapshotv");
    if (snap_pc < 0) fprintf(stderr, "fil: warning: no enc_snapshot() in %s: no encoder check\n", elf);
    char err[512];
    if (avrsim_open(&sim, elf, err, sizeof err)) die("%s", err);
    avr = sim.avr;
    // INT4..INT7 (PE4..PE7) are never enabled by the firmware (EIMSK |= 0x0F), but their sense
    // control stays at 00 (low level) and PE5 is the right motor's PWM pin: simavr's "strict"
    // low-level emulation then polls the pin on every cycle while it is low (motors off), which
    // made the simulation ~2-3x slower. Non-strict: no polling; the disabled vectors are unaffected.
    for (uint8_t i = 4; i < 8; ++i) avr_extint_set_strict_lvl_trig(avr, i, 0);
}

void Fil::step() {
    avrsim_step(&sim);
    if (static_cast<long>(avr->pc) == snap_pc && board_origin_set) {
        Snap sn{board_now(), counts_at(0, avr->cycle), counts_at(1, avr->cycle), pos_now[0], pos_now[1]};
        snaps.push_back(sn);
        while (snaps.size() > 400) snaps.pop_front();
        ++snap_calls;
        if (snap_f) fprintf(snap_f, "%.7f,%.4f,%.4f,%ld,%ld,%u\n", sn.t, sn.s_r, sn.s_l, sn.pins_r, sn.pins_l,
                            static_cast<unsigned>(boot_at_s.size()));
    }
}

void Fil::after_step() {
    bool br = (avr->data[MOTOR_BRAKE_PORT] & MOTOR_BRAKE_MASK) == MOTOR_BRAKE_MASK;  // at the exact cycle
    if (br != braking) {
        (br ? brake_on_t : brake_off_t).push_back(board_now());
        braking = br;
    }
    bool t5 = avr->data[CYCLES_TCCRB] != 0;
    if (t5 && !board_running) {
        board_running = true;
        if (!board_origin_set) { board_origin = avr->cycle; board_origin_set = true; next_cam_t = 0; }
        boot_at_s.push_back(board_now());
    } else if (!t5 && board_running) {
        board_running = false;
        avrsim_abandon_isrs(&sim);  // a reset abandons any ISR in progress
        reset_at_s.push_back(board_now());
    }
    if (avr->cycle > next_plant_at + plant_cycles) {  // a reset cleared the cycle timers
        next_plant_at = avr->cycle;
        arm_plant(0);
        edge_armed[0] = edge_armed[1] = false;
        arm_edges(0);
        arm_edges(1);
        if (!down_q.empty()) arm_down(byte_cycles);
        else down_armed = false;
    }
}

void Fil::arm_plant(avr_cycle_count_t in_cycles) {
    avr_cycle_timer_register(avr, in_cycles,
                             [](avr_t*, avr_cycle_count_t when, void* p) { return static_cast<Fil*>(p)->plant_cb(when); },
                             this);
}

}  // namespace fil
