// Scheduler on the (simulated) ATmega2560: release times from the 1 kHz tick, cycle
// measurement of each run with the Timer5 clock, overruns for budget excess and for missed
// releases. The tasks are busy loops of known length (_delay_loop_2: 4 cycles per count).
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/delay_basic.h>
#include <unity.h>

#include "cycles.h"
#include "sched.h"

namespace {
volatile uint16_t g_loops_a = 1000;   // 4,000 cycles
volatile uint16_t g_loops_b = 5000;   // 20,000 cycles
volatile uint16_t g_runs_a, g_runs_b;
volatile uint32_t g_release_ms_a[8];

void task_a() {
    if (g_runs_a < 8) g_release_ms_a[g_runs_a] = sched_ms();
    g_runs_a = g_runs_a + 1;
    _delay_loop_2(g_loops_a);
}
void task_b() {
    g_runs_b = g_runs_b + 1;
    _delay_loop_2(g_loops_b);
}

const TaskConfig kTasks[] = {
    {task_a, 5, 0, 10000},   // every 5 ms, budget 10,000 cycles
    {task_b, 10, 2, 15000},  // every 10 ms from 2 ms, budget 15,000: 20,000 overruns it
};

void run_until_ms(uint32_t end_ms) {
    while (sched_ms() < end_ms) {
        if (!sched_run_one()) sched_idle();
    }
}
}  // namespace

void setUp() {
    g_runs_a = g_runs_b = 0;
    cycles_init();
    sched_init(kTasks, 2);
    sei();
}
void tearDown() {}

static void test_releases_follow_period_and_phase() {
    run_until_ms(41);
    TEST_ASSERT_EQUAL_UINT16(9, g_runs_a);  // 0, 5, ..., 40
    TEST_ASSERT_EQUAL_UINT16(4, g_runs_b);  // 2, 12, 22, 32
    for (uint8_t i = 0; i < 8; ++i) {
        // released on its tick, or one tick late when task_b (1.25 ms) was running
        TEST_ASSERT_UINT32_WITHIN(1, 5ul * i, g_release_ms_a[i]);
    }
}

static void test_measures_execution_cycles() {
    run_until_ms(30);
    const TaskStats& a = sched_stats(0);
    const TaskStats& b = sched_stats(1);
    // busy loop + call overhead + the 1 kHz tick ISR (~70 cycles) when it lands in the run
    TEST_ASSERT_UINT32_WITHIN(300, 4100, a.last_cycles);
    TEST_ASSERT_UINT32_WITHIN(400, 20150, b.last_cycles);
    TEST_ASSERT_TRUE(a.max_cycles >= a.last_cycles);
}

static void test_counts_budget_overruns() {
    run_until_ms(41);
    TEST_ASSERT_EQUAL_UINT16(0, sched_stats(0).overruns);
    TEST_ASSERT_EQUAL_UINT16(4, sched_stats(1).overruns);  // every run of b exceeds 15,000
}

static const TaskConfig kSlow[] = {
    {task_b, 10, 0, 1000000ul},  // budget never exceeded: only missed releases count
};

static void test_counts_missed_releases() {
    g_loops_b = 50000;  // 200,000 cycles = 12.5 ms > its 10 ms period
    sched_init(kSlow, 1);
    run_until_ms(40);
    g_loops_b = 5000;
    const TaskStats& b = sched_stats(0);
    TEST_ASSERT_TRUE(b.max_cycles > 199000ul && b.max_cycles < 1000000ul);
    TEST_ASSERT_TRUE(b.runs >= 2);
    TEST_ASSERT_EQUAL_UINT16(b.runs, b.overruns);  // every run ran past its next release
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_releases_follow_period_and_phase);
    RUN_TEST(test_measures_execution_cycles);
    RUN_TEST(test_counts_budget_overruns);
    RUN_TEST(test_counts_missed_releases);
    UNITY_END();
    cli();
    sleep_cpu();
    return 0;
}
