// Cooperative scheduler: a 1 kHz tick (Timer4, CTC) releases the tasks of a constant table
// (period, phase, cycle budget); the main loop runs due tasks in table order, measures each
// run with the Timer5 cycle clock and counts overruns.
// Overrun = a run that took more cycles than its budget, or a release that was missed
// because the previous run of any task was still going (the task then restarts on time).
#ifndef FW_SCHED_H
#define FW_SCHED_H

#include <stdint.h>

struct TaskConfig {          // constant configuration (flash-resident table in the app)
    void (*run)();
    uint16_t period_ms;
    uint16_t phase_ms;       // first release
    uint32_t budget_cycles;
};

struct TaskStats {           // runtime data, read by telemetry
    uint32_t last_cycles;
    uint32_t max_cycles;
    uint16_t overruns;       // saturating
    uint16_t runs;           // wraps
};

static const uint8_t kMaxTasks = 4;

void sched_init(const TaskConfig* tasks, uint8_t n);
// Milliseconds since sched_init (1 kHz tick), wraps after 49 days.
uint32_t sched_ms();
// Runs at most one due task (the first in table order). Returns true when it ran one.
bool sched_run_one();
// Sleeps (idle mode) until the next interrupt, unless a task is already due.
void sched_idle();
const TaskStats& sched_stats(uint8_t i);
// Called from a running task: task i is next released period_ms after the running task's
// release (so that a loop can be restarted in phase with an event, e.g. an experiment's start).
void sched_restart_after_current(uint8_t i);
// Clears last/max/overruns/runs of every task.
void sched_reset_stats();

#endif  // FW_SCHED_H
