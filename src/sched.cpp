#include "sched.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "board.h"
#include "cycles.h"
#include "motor.h"

namespace {
const TaskConfig* g_tasks;
uint8_t g_n;
uint32_t g_next_ms[kMaxTasks];
uint32_t g_next_due_ms;  // min of g_next_ms: lets sched_idle() decide in a few cycles
TaskStats g_stats[kMaxTasks];
uint32_t g_current_release_ms;  // release time of the task sched_run_one() is running
volatile uint32_t g_ms;

uint32_t now_ms() {
    uint8_t sreg = SREG;
    cli();
    uint32_t t = g_ms;
    SREG = sreg;
    return t;
}
bool due(uint8_t i, uint32_t now) { return static_cast<int32_t>(now - g_next_ms[i]) >= 0; }
void sat_inc(uint16_t* c) {
    if (*c != 0xFFFFu) ++*c;
}
}  // namespace

// NOBLOCK: interrupts are re-enabled at once, so an encoder edge waits only for the few
// cycles of the prologue (the compare flag is cleared on entry; the ISR cannot re-enter itself).
ISR(SCHED_TICK_VECT, ISR_NOBLOCK) {
    g_ms = g_ms + 1;
    motor_ramp_tick();  // the duty ramp of the torque->PWM map
    motor_sense_start();  // the current pair (A0, A1: 208 us), fresh for whatever reads it
}

namespace {
void update_next_due() {
    uint32_t m = g_next_ms[0];
    for (uint8_t i = 1; i < g_n; ++i)
        if (static_cast<int32_t>(g_next_ms[i] - m) < 0) m = g_next_ms[i];
    g_next_due_ms = m;
}
}  // namespace

void sched_init(const TaskConfig* tasks, uint8_t n) {
    g_tasks = tasks;
    g_n = n > kMaxTasks ? kMaxTasks : n;
    uint8_t sreg = SREG;
    cli();
    g_ms = 0;
    // The tick timer in CTC mode, clk/64: 250 kHz, TOP = 249 -> 1 kHz (board.h).
    SCHED_TCCRB = 0;  // configure with the clock stopped, start it last
    SCHED_TCCRA = 0;
    SCHED_OCR = SCHED_TOP;
    SCHED_TCNT = 0;
    SCHED_TCCRB = SCHED_TCCRB_RUN;
    SCHED_TIFR = _BV(SCHED_OCF);
    SCHED_TIMSK = _BV(SCHED_OCIE);
    SREG = sreg;
    for (uint8_t i = 0; i < g_n; ++i) g_next_ms[i] = g_tasks[i].phase_ms;
    update_next_due();
    sched_reset_stats();
}

void sched_restart_after_current(uint8_t i) {
    if (i >= g_n) return;
    g_next_ms[i] = g_current_release_ms + g_tasks[i].period_ms;
    update_next_due();
}

void sched_reset_stats() {
    for (uint8_t i = 0; i < g_n; ++i) g_stats[i] = TaskStats{0, 0, 0, 0};
}

uint32_t sched_ms() { return now_ms(); }

bool sched_run_one() {
    uint32_t now = now_ms();
    for (uint8_t i = 0; i < g_n; ++i) {
        if (!due(i, now)) continue;
        const TaskConfig& t = g_tasks[i];
        g_current_release_ms = g_next_ms[i];
        uint32_t c0 = cycles_now();
        t.run();
        uint32_t dc = cycles_now() - c0;
        TaskStats& s = g_stats[i];
        s.last_cycles = dc;
        if (dc > s.max_cycles) s.max_cycles = dc;
        if (dc > t.budget_cycles) sat_inc(&s.overruns);
        ++s.runs;
        g_next_ms[i] += t.period_ms;
        uint32_t after = now_ms();
        if (due(i, after)) {  // already due again: a release was missed
            sat_inc(&s.overruns);
            g_next_ms[i] = after + t.period_ms;
        }
        update_next_due();
        return true;
    }
    return false;
}

void sched_idle() {
    set_sleep_mode(SLEEP_MODE_IDLE);
    uint32_t next = g_next_due_ms;
    cli();  // ~12 cycles: read the tick, compare, sleep
    uint32_t now = g_ms;
    if (static_cast<int32_t>(now - next) < 0) {
        sleep_enable();
        sei();        // the instruction after SEI runs before any interrupt: no lost wake-up
        sleep_cpu();
        sleep_disable();
    }
    sei();
}

const TaskStats& sched_stats(uint8_t i) { return g_stats[i < g_n ? i : 0]; }
