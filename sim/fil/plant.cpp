// Plant coupling: the motor outputs (timer and pin registers) drive lib/slipmodel's plant in
// lockstep with the simulated core; pacing against the wall clock.
#include "fil.h"

#include <math.h>
#include <time.h>

namespace fil {

// Wall-clock seconds since the start (pacing).
double Fil::wall_now() const {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return static_cast<double>(t.tv_sec - wall0.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec - wall0.tv_nsec);
}

// Signed duty of one shield channel from the timer/pin registers: fast PWM (WGM 14, TOP = ICRn)
// non-inverting: the output is high for OCR + 1 of TOP + 1 counts (100 % when OCR >= TOP);
// COM bits off: the pin is a plain output (PORT level). BRAKE high: both L298 inputs equal ->
// no drive voltage (terminals shorted while enable is high): duty 0. The plant's duty model
// gives the averaged voltage u * supply; enable low (coast) is approximated by u = 0 as well.
double Fil::channel_duty(int w) {
    bool right = w == 0;
    bool brake = avr->data[MOTOR_BRAKE_PORT] & (1u << (right ? MOTOR_R_BRAKE_BIT : MOTOR_L_BRAKE_BIT));
    if (brake) return 0.0;
    uint8_t tccra = avr->data[right ? MOTOR_R_TCCRA : MOTOR_L_TCCRA];
    bool com = tccra & (1u << (right ? MOTOR_R_COM1 : MOTOR_L_COM1));
    double mag;
    if (com) {
        double top = avrsim_rd16(&sim, right ? MOTOR_R_ICR : MOTOR_L_ICR);
        double ocr = avrsim_rd16(&sim, right ? MOTOR_R_OCR : MOTOR_L_OCR);
        if (opt.pwm_ideal) mag = ocr >= top + 1 ? 1.0 : ocr / (top + 1.0);
        else mag = ocr >= top ? 1.0 : (ocr + 1.0) / (top + 1.0);
    } else {
        uint8_t port = avr->data[right ? MOTOR_R_PWM_PORT : MOTOR_L_PWM_PORT];
        mag = (port & (1u << (right ? MOTOR_R_PWM_BIT : MOTOR_L_PWM_BIT))) ? 1.0 : 0.0;  // a plain output
    }
    int level = (avr->data[MOTOR_DIR_PORT] >> (right ? MOTOR_R_DIR_BIT : MOTOR_L_DIR_BIT)) & 1;
    int fwd_level = right ? MOTOR_RIGHT_DIR_FORWARD_LEVEL : MOTOR_LEFT_DIR_FORWARD_LEVEL;
    return level == fwd_level ? mag : -mag;
}

// ------------------------------------------------------------------------ plant step
void Fil::pace() {
    if (opt.realtime <= 0 || stepping) return;  // stepping: the host is the clock
    double target = wall_at_pace0 + (board_now() - sim_t_at_pace0) / opt.realtime;
    double now = wall_now();
    if (target > now + 0.001) {
        double d = target - now;
        struct timespec ts = {static_cast<time_t>(d), static_cast<long>((d - floor(d)) * 1e9)};
        nanosleep(&ts, nullptr);
    }
}

// Every plant step: the motor outputs -> Plant::step_duty over the next interval, the wheel
// angles -> encoder edges, the camera samples and plant.csv, the host's bytes, hang injection.
avr_cycle_count_t Fil::plant_cb(avr_cycle_count_t when) {
    if (((avr->data[ENC_PIN] ^ pins_driven) & ENC_MASK) && edges[0].empty() && edges[1].empty()) ++pin_conflicts;
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
    // stepping (--lockstep): the host's bytes are read at the holds only; with --lockstep none
    // in the first 50 ms of board time either (Options::boot_s, where the simulator waits for
    // the host): the firmware's start-up is then the same in every run
    if (!stepping && !(opt.lockstep && (!board_origin_set || board_now() < opt.boot_s))) {
        if (!poll_host() && opt.exit_on_hangup) { stop_now = true; stop_reason = "host closed the link"; }
        if (opt.lockstep) poll_control();
    }
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

}  // namespace fil
