// The robot application: experiment state machine, control tasks, telemetry and commands.
// Tasks (run by the scheduler, table in app.cpp):
//   inner     25 ms  encoder snapshot, odometry, velocity/torque loop, tau_max clamp, PWM
//   outer     50 ms  reference sample, kinematic tracking law
//   telemetry 20 ms  Telemetry frame (protocol/protocol.json) queued on the XBee link
// Background (main loop): host command decoding; the replies (Ack, Params), kept until the TX
// ring has room and sent before telemetry; 500 ms host-timeout failsafe.
#ifndef FW_APP_H
#define FW_APP_H

#include <stdint.h>

#include "sched.h"

void app_init();
// Main-loop work between tasks: received bytes, commands, failsafe checks.
void app_poll();
const TaskConfig* app_tasks();
uint8_t app_task_count();

// Test/simulator hook: a non-zero value makes the main loop hang (the watchdog test).
extern "C" volatile uint8_t g_fault_hang;

#endif  // FW_APP_H
